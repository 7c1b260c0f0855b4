// `rekon render MESH --out FILE.png`: an offscreen shaded image of a colored mesh.
#include <chrono>
#include <iostream>
#include <sstream>

#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/image_io.hpp"
#include "rekon/common/json.hpp"
#include "rekon/render/render.hpp"

namespace rekon::render {
namespace {

View parseView(const std::string& text) {
  std::istringstream ss(text);
  double v[6];
  char comma = 0;
  for (int i = 0; i < 6; ++i) {
    if (!(ss >> v[i])) throw Error("--view '" + text + "' must be auto or x,y,z,tx,ty,tz (eye, then target)");
    if (i < 5 && (!(ss >> comma) || comma != ',')) throw Error("--view '" + text + "' must be auto or x,y,z,tx,ty,tz (eye, then target)");
  }
  std::string rest;
  if (ss >> rest) throw Error("--view '" + text + "' has extra text; give x,y,z,tx,ty,tz");
  return {Eigen::Vector3d(v[0], v[1], v[2]), Eigen::Vector3d(v[3], v[4], v[5])};
}

Eigen::Vector3d parseUp(const std::string& text) {
  if (text == "z" || text == "+z") return Eigen::Vector3d::UnitZ();
  if (text == "-z") return -Eigen::Vector3d::UnitZ();
  if (text == "y" || text == "+y") return Eigen::Vector3d::UnitY();
  if (text == "-y") return -Eigen::Vector3d::UnitY();
  if (text == "x" || text == "+x") return Eigen::Vector3d::UnitX();
  if (text == "-x") return -Eigen::Vector3d::UnitX();
  throw Error("--up '" + text + "' must be one of x, -x, y, -y, z, -z");
}

Cull parseCull(const std::string& text) {
  if (text == "back") return Cull::Back;
  if (text == "front") return Cull::Front;
  if (text == "none") return Cull::None;
  throw Error("--cull '" + text + "' must be back, front or none");
}

}  // namespace

int renderCommand(int argc, char** argv) {
  ArgParser args(argv[0], "Render a colored mesh (PLY) to a PNG offscreen on the CPU (Lambert-lit vertex colors).");
  args.positional("MESH", "mesh to render (PLY)")
      .option("out", "output image (.png)")
      .option("view", "auto, or eye and target as x,y,z,tx,ty,tz", "auto")
      .option("width", "image width", std::to_string(RenderOptions::kDefaultWidth))
      .option("height", "image height", std::to_string(RenderOptions::kDefaultHeight))
      .option("fov", "vertical field of view (degrees)", "45")
      .option("up", "up axis of the mesh: x, -x, y, -y, z, -z; rekon's meshes are in the first camera's frame, whose y "
                    "points down (-y); z for z-up world frames", "-y")
      .option("cull", "back (see a room's inside through its near walls), front or none", "back")
      .examples("rekon render out/demo/mesh.ply --out room.png\n"
                "rekon render mesh.ply --out top.png --view 0,-4,2,0,0,2 --width 1280 --height 960\n"
                "rekon render reference.ply --out ref.png --up z   # a z-up world frame");
  if (!args.parse(argc, argv)) return 0;
  if (!args.has("out")) throw Error("missing --out FILE.png; see " + std::string(argv[0]) + " --help");
  RenderOptions o;
  o.width = args.getInt("width");
  o.height = args.getInt("height");
  o.fov_y_deg = args.getDouble("fov");
  o.up = parseUp(args.get("up"));
  o.cull = parseCull(args.get("cull"));
  if (args.get("view") != "auto") o.view = parseView(args.get("view"));
  const auto start = std::chrono::steady_clock::now();
  const Mesh mesh = readPly(args.get("MESH"));
  const cv::Mat image = renderMesh(mesh, o);
  writeImage(args.get("out"), image);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  size_t covered = 0;
  for (int y = 0; y < image.rows; ++y)
    for (int x = 0; x < image.cols; ++x) covered += image.at<cv::Vec3b>(y, x) != o.background;
  std::cout << "rendered " << mesh.triangles.size() << " triangles to " << args.get("out") << "\n"
            << keyValueLine({{"width", o.width},
                             {"height", o.height},
                             {"triangles", static_cast<double>(mesh.triangles.size())},
                             {"coverage", static_cast<double>(covered) / (static_cast<double>(image.rows) * image.cols)},
                             {"seconds", seconds}})
            << "\n";
  return 0;
}

}  // namespace rekon::render
