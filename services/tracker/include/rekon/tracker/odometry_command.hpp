#pragma once
// `rekon odometry`: the tracker in-process on a TUM-layout dataset.

namespace rekon::tracker {

int odometryMain(int argc, char** argv);

}  // namespace rekon::tracker
