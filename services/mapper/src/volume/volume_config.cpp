#include "rekon/mapper/volume/volume_config.hpp"

namespace rekon::volume {

VolumeParams volumeParamsFromConfig(const Config& config) {
  VolumeParams p;
  p.voxel_size = config.getDouble("volume.voxel_size");
  p.truncation = config.getDouble("volume.truncation");
  p.max_depth = config.getDouble("volume.max_depth");
  p.block_capacity = config.getInt("volume.block_capacity");
  p.grow_capacity = config.getBool("volume.grow_capacity");
  p.streaming_radius = config.getDouble("volume.streaming_radius");
  p.weight_units = config.getDouble("volume.weight_units");
  p.allocation_stride = config.getInt("volume.allocation_stride");
  p.backend = config.getString("volume.backend");
  p.cpu_threads = config.getInt("volume.cpu_threads");
  p.validate();
  return p;
}

}  // namespace rekon::volume
