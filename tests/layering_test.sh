#!/usr/bin/env bash
# The libraries' dependencies point one way: tools -> client and service -> transport -> engine.
# Fails, naming the file and the include, when a source includes a header of a layer above it
# (or one it must not need: the client needs no scene generator, admission needs no DDS).
# Usage: tests/layering_test.sh SOURCE_DIR
set -u
src="${1:?usage: layering_test.sh SOURCE_DIR}"
cd "$src" || exit 2
status=0

# forbid DIR PATTERN WHY: no #include under DIR may match the extended regex PATTERN.
forbid() {
  local dir=$1 pattern=$2 why=$3 hits
  hits=$(grep -rnE --include='*.h' --include='*.cc' "^[[:space:]]*#[[:space:]]*include[[:space:]]*[<\"]($pattern)" "$dir")
  if [[ -n "$hits" ]]; then
    echo "layering: $dir must not include ($why):"
    echo "$hits" | sed 's/^/  /'
    status=1
  fi
}

service_headers='config\.h|yaml_reader\.h|engine_host\.h|daemon\.h|keep_awake\.h'
forbid engine "bp/(transport|client|tools|util)/|broadphase\.pb\.h|envelope\.h|dds/|$service_headers" \
  "the engine depends on the C++ standard library only"
forbid transport "bp/(client|tools)/|$service_headers" "the transport is below the client and the service"
forbid client "bp/tools/|bp/workload|$service_headers" "the client is beside the service, and needs no scene generator"
forbid service "bp/(client|tools)/" "the daemon is beside the client, below the tools"
forbid service/admission "bp/transport/(dds|connection)\.h|dds/|daemon\.h|keep_awake\.h" \
  "admission (shared with bpctl check) needs no DDS"
forbid util "bp/" "the utilities depend on nothing of the project's"

if [[ $status -eq 0 ]]; then echo "layering: every include points down"; fi
exit $status
