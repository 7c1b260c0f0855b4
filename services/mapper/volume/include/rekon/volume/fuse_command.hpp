#pragma once
// `rekon fuse`: integrates a TUM-layout dataset at given poses into the TSDF
// volume and writes the mesh (e.g. the reference mesh from ground truth).

namespace rekon::volume {

int fuseMain(int argc, char** argv);

}  // namespace rekon::volume
