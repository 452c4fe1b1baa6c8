# cmake -DDIR=server/core -P check_includes.cmake: fails if a file of the server's core includes a wire
# format or a transport (protobuf, gRPC, the generated dance.v1 code, a JSON library, server/grpc/,
# server/web/). The core speaks engine types and plain structs; the transports encode.
file(GLOB files ${DIR}/*.h ${DIR}/*.cc)
set(bad "")
foreach(f ${files})
  file(STRINGS ${f} lines REGEX "^[ \t]*#[ \t]*include[ \t]*[<\"](google/protobuf/|grpc|dance/v1/|nlohmann/|server/grpc/|server/web/)")
  foreach(line ${lines})
    list(APPEND bad "${f}: ${line}")
  endforeach()
endforeach()
if(bad)
  list(JOIN bad "\n  " text)
  message(FATAL_ERROR "server/core must not include a wire format or a transport:\n  ${text}")
endif()
