#pragma once
// The `volume` section of the rekon configuration as VolumeParams.
#include "rekon/common/config.hpp"
#include "rekon/mapper/volume/tsdf_volume.hpp"

namespace rekon::volume {

// Reads every volume.* key and validates the result (rekon::Error naming the key).
VolumeParams volumeParamsFromConfig(const Config& config);

}  // namespace rekon::volume
