// The connection the client library's publishers and subscribers take: a participant joined to
// a deployment, from the transport library (bp/transport/connection.h), named here in the
// client's namespace for its users.
#pragma once

#include "bp/transport/connection.h"

namespace bp::client {

using transport::Connection;
using transport::ConnectionOptions;
using transport::ReadTextFile;
using transport::TopicId;
using transport::TopicNames;
namespace qos = transport::qos;

}  // namespace bp::client
