#include "camera_service.hpp"
#include "rekon/common/error.hpp"

int main(int argc, char** argv) {
  return rekon::runService(
      argc, argv, "camera", "Publishes a live RGB-D camera's frames on the rekon bus (OpenNI2 or libfreenect).",
      [](rekon::ArgParser& args) {
        args.option("device", "openni2[:URI] or freenect[:INDEX]; overrides camera.device")
            .option("calibration", "camera.yaml for the device; overrides camera.calibration")
            .option("record", "record every captured frame into this new TUM folder; overrides camera.record");
      },
      [](rekon::ServiceContext& ctx) {
        rekon::Config config = ctx.config();
        for (const char* key : {"device", "calibration", "record"}) {
          if (ctx.args().has(key)) config.set(std::string("camera.") + key, ctx.args().get(key));
        }
        rekon::camera::runCamera(ctx, rekon::camera::CameraParams::fromConfig(config));
      });
}
