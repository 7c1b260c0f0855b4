#pragma once
// `rekon eval traj GT EST [--json]` and `rekon eval surface MESH REF [--json]`.

namespace rekon::eval {

int evalCommand(int argc, char** argv);

}  // namespace rekon::eval
