#pragma once

namespace rekon {

// `rekon listen --out FILE`: receives frames from the bus as a consumer named
// "listener" (heartbeats and acknowledgements, so a player paces itself to
// it), writes "frame_id timestamp hash" per frame, and stops at the end of
// the stream. `rekon listen --mesh OUT.ply`: assembles the mapper's mesh from
// MESH_BLOCKS (asking for a full snapshot first) and writes it when the
// mapper is done.
int listenMain(int argc, char** argv);

}  // namespace rekon
