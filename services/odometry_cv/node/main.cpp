// rekon-odometry_cv: OpenCV's RGB-D odometry as a rekon frontend (see odometry_cv_service.hpp).
#include "odometry_cv_service.hpp"

int main(int argc, char** argv) {
  return rekon::runService(
      argc, argv, "odometry_cv",
      "Tracks the frames rekon-player announces with OpenCV's RGB-D odometry (contrib rgbd: photometric + ICP) "
      "against keyframes, and publishes keyframes, tracked frames with their covariance, graph updates and done_t "
      "for rekon-mapper (in place of rekon-tracker and rekon-optimiser); writes trajectory.txt to --out.",
      nullptr, [](rekon::ServiceContext& ctx) { rekon::odometry_cv::runOdometryCvService(ctx); });
}
