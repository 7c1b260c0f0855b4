#pragma once

namespace rekon {

// `rekon listen --out FILE`: receives frames from the bus as a consumer named
// "listener" (heartbeats and acknowledgements, so a player paces itself to
// it), writes "frame_id timestamp hash" per frame, and stops at the end of
// the stream.
int listenMain(int argc, char** argv);

}  // namespace rekon
