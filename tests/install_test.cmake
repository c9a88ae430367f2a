# Installs the build tree into a scratch prefix, then configures, builds and runs the standalone
# examples against it: the engine alone (find_package(broadphase)), the client library
# (find_package(broadphase COMPONENTS client)) and, with Bullet, the Bullet producer.
# Arguments: -DBUILD_DIR= -DSOURCE_DIR= -DWORK_DIR= -DCXX_FLAGS= (the build's sanitizer flags)
# -DWITH_BULLET= (build examples/bullet_world too)
file(REMOVE_RECURSE ${WORK_DIR})

# Configures and builds examples/<name> against the installed package into <build>.
function(build_example name build)
  execute_process(COMMAND ${CMAKE_COMMAND} -S ${SOURCE_DIR}/examples/${name} -B ${build} -G Ninja
    -DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix "-DCMAKE_CXX_FLAGS=${CXX_FLAGS}" RESULT_VARIABLE rc)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "configuring ${name} against the installed package failed: ${rc}")
  endif()
  execute_process(COMMAND ${CMAKE_COMMAND} --build ${build} RESULT_VARIABLE rc)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "building ${name} failed: ${rc}")
  endif()
endfunction()

execute_process(COMMAND ${CMAKE_COMMAND} --install ${BUILD_DIR} --prefix ${WORK_DIR}/prefix
  RESULT_VARIABLE rc OUTPUT_QUIET)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "install failed: ${rc}")
endif()
build_example(engine_standalone ${WORK_DIR}/build)
execute_process(COMMAND ${WORK_DIR}/build/engine_standalone RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "the example reported wrong events: ${rc}")
endif()

# The client library: configure, build and run (no daemon on that domain: it builds a batch,
# waits briefly and says so).
build_example(client_standalone ${WORK_DIR}/client-build)
execute_process(COMMAND ${WORK_DIR}/client-build/client_standalone 15 200 RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "the client example failed: ${rc}")
endif()

# The Bullet producer, where Bullet is installed: configure and build it standalone, then run it
# with no daemon on the domain (it must say so and exit 2).
if(WITH_BULLET)
  build_example(bullet_world ${WORK_DIR}/bullet-build)
  execute_process(COMMAND ${WORK_DIR}/bullet-build/bullet_world --domain 15 --wait 0.3
    RESULT_VARIABLE rc ERROR_VARIABLE err)
  if(NOT rc EQUAL 2 OR NOT err MATCHES "no daemon")
    message(FATAL_ERROR "bullet_world without a daemon: exit ${rc}, ${err}")
  endif()
endif()

# The components: each loads what it names (and the engine), and an unknown one is refused.
file(MAKE_DIRECTORY ${WORK_DIR}/components)
file(WRITE ${WORK_DIR}/components/CMakeLists.txt [=[
cmake_minimum_required(VERSION 3.25)
project(components LANGUAGES C CXX)
find_package(broadphase 0.1 REQUIRED CONFIG COMPONENTS transport)
if(NOT TARGET broadphase::transport OR NOT TARGET broadphase::engine OR TARGET broadphase::engines
   OR TARGET broadphase::client)
  message(FATAL_ERROR "COMPONENTS transport loaded the wrong targets")
endif()
find_package(broadphase 0.1 CONFIG COMPONENTS no_such_component QUIET)
if(broadphase_FOUND)
  message(FATAL_ERROR "an unknown component was accepted")
endif()
]=])
execute_process(COMMAND ${CMAKE_COMMAND} -S ${WORK_DIR}/components -B ${WORK_DIR}/components/build
  -G Ninja -DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "the package's components load the wrong targets: ${rc}")
endif()
