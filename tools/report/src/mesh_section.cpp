#include <spdlog/spdlog.h>

#include <cmath>
#include <numbers>

#include "rekon/common/error.hpp"
#include "rekon/common/mesh.hpp"
#include "rekon/eval/surface_eval.hpp"
#include "rekon/eval/trajectory_eval.hpp"
#include "rekon/render/render.hpp"
#include "rekon/report/html.hpp"
#include "report_sections.hpp"

namespace rekon::report {
namespace fs = std::filesystem;
namespace {

// A camera looks along its z with y down, so its world "up" is -y. Averaged
// over a hand-held or robot trajectory this is the gravity up of the scene,
// in whatever frame the run's poses are (the first camera's, or the ground truth's).
Eigen::Vector3d upFromCameras(const std::optional<Trajectory>& t) {
  constexpr double kMinAgreement = 0.5;  // cameras rolling all over: no usable up
  if (!t || t->empty()) return Eigen::Vector3d::UnitZ();
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (const auto& p : *t) sum += p.pose.linear() * Eigen::Vector3d(0, -1, 0);
  const Eigen::Vector3d mean = sum / static_cast<double>(t->size());
  return mean.norm() > kMinAgreement ? mean.normalized() : Eigen::Vector3d::UnitZ();
}

// Straight down along `up`, the longer horizontal extent across the image.
render::RenderOptions topViewOptions(const Mesh& mesh, render::RenderOptions o) {
  const Eigen::Vector3d up = o.up.normalized();
  const Eigen::Vector3d ref = std::abs(up.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  const Eigen::Vector3d e1 = up.cross(ref).normalized(), e2 = up.cross(e1);
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (const auto& v : mesh.vertices) {
    const Eigen::Vector3d p = v.cast<double>();
    const Eigen::Vector3d q(p.dot(e1), p.dot(e2), p.dot(up));
    lo = lo.cwiseMin(q);
    hi = hi.cwiseMax(q);
  }
  const Eigen::Vector3d c = 0.5 * (lo + hi), half = 0.5 * (hi - lo);
  const bool e1_across = half.x() >= half.y();
  const double across = std::max(half.x(), half.y()), along = std::min(half.x(), half.y());
  const double tan_y = std::tan(0.5 * o.fov_y_deg * std::numbers::pi / 180.0);
  const double tan_x = tan_y * o.width / o.height;
  constexpr double kFill = 0.92;
  const double distance = std::max(across / tan_x, along / tan_y) / kFill + half.z();
  const Eigen::Vector3d centre = c.x() * e1 + c.y() * e2 + c.z() * up;
  o.view = render::View{centre + up * distance, centre};
  o.up = e1_across ? e2 : e1;  // image up: the shorter horizontal extent
  return o;
}

struct MeshFile {
  std::string name, note;
  std::optional<Mesh> mesh;
};

MeshFile loadMesh(const fs::path& run, const std::string& name, const std::string& why_absent, Page& page) {
  MeshFile f{name, "", std::nullopt};
  const fs::path path = run / name;
  if (!fs::exists(path)) {
    page.absentInput(name + ": " + why_absent);
    return f;
  }
  try {
    f.mesh = readPly(path.string());
  } catch (const Error& e) {
    page.absentInput(name + ": unreadable (" + std::string(e.what()) + ")");
    return f;
  }
  if (f.mesh->triangles.empty()) {
    page.absentInput(name + ": has no triangles");
    f.mesh.reset();
    return f;
  }
  f.note = std::to_string(f.mesh->vertices.size()) + " vertices, " + std::to_string(f.mesh->triangles.size()) + " triangles";
  return f;
}

// CORR (mesh to ground truth) and COMPL (ground truth to mesh) of each mesh,
// moved from the run's world (its first camera) into the ground truth's.
void surfaceErrorTable(Page& page, const std::vector<const MeshFile*>& meshes, const std::string& gt_path,
                       const TrajectoryInputs& in) {
  const auto alignment = in.estimate && in.ground_truth ? eval::firstPoseAlignment(*in.estimate, *in.ground_truth)
                                                        : std::nullopt;
  if (!alignment) {
    page.absentInput("surface errors: " + gt_path + " is there, but no ground-truth pose at the run's first frame to "
                     "place the mesh in its frame");
    return;
  }
  Mesh gt;
  try {
    gt = readPly(gt_path);
  } catch (const Error& e) {
    page.absentInput("ground-truth mesh: unreadable (" + std::string(e.what()) + ")");
    return;
  }
  std::vector<std::vector<std::string>> rows;
  bool compl_at_cap = false;
  for (const MeshFile* f : meshes) {
    if (!f->mesh) continue;
    Mesh moved = *f->mesh;
    const Eigen::Isometry3f t = alignment->cast<float>();
    for (auto& v : moved.vertices) v = t * v;
    const eval::SurfaceErrors e = eval::evaluateSurface(moved, gt);
    compl_at_cap |= e.compl_median_m >= e.cap_m;
    rows.push_back({f->name, number(e.corr_m * 1e3, 2), number(e.corr_median_m * 1e3, 2), number(e.compl_m * 1e3, 2),
                    number(e.compl_median_m * 1e3, 2), number(e.compl_within_1cm * 100.0, 1)});
  }
  page.body << "<p>Against the dataset's ground-truth surface <code>" << escapeHtml(gt_path)
            << "</code>, each mesh placed in its frame by the first camera's ground-truth pose (CORR: mesh vertices to "
               "it; COMPL: points on it to the mesh; distances capped at "
            << number(eval::SurfaceEvalOptions::kDefaultCapM * 1e3, 0) << " mm; as <code>rekon eval surface</code>):</p>\n";
  page.table({"mesh", "CORR mean [mm]", "CORR median [mm]", "COMPL mean [mm]", "COMPL median [mm]", "COMPL within 1 cm [%]"},
             rows);
  if (compl_at_cap) {
    page.body << "<p>A COMPL median at the cap means that more than half of the ground-truth surface is farther than "
              << number(eval::SurfaceEvalOptions::kDefaultCapM * 1e3, 0)
              << " mm from the mesh: parts the camera never saw (a room's floor far below a camera looking at the walls, "
                 "the backs of objects) count at the cap. COMPL within 1 cm says how much of it the scan covered.</p>\n";
  }
}

}  // namespace

void meshSection(Page& page, const fs::path& run, const RunReportOptions& options, const TrajectoryInputs& in,
                 const std::string& gt_mesh) {
  page.body << "<h2>Mesh</h2>\n";
  const MeshFile final_mesh = loadMesh(run, "mesh.ply", "not written (the run has no mapper, or it stopped early)", page);
  const MeshFile uncorrected = loadMesh(run, "mesh_uncorrected.ply", "not written (kept only when surface correction is on)", page);
  if (!final_mesh.mesh && !uncorrected.mesh) {
    page.body << "<p>No mesh to show.</p>\n";
    return;
  }
  page.body << "<p><code>mesh.ply</code> is the corrected surface: every KF keyframe re-integrated at its optimised pose "
               "as the pose graph changed, and once more in the final pass. <code>mesh_uncorrected.ply</code> is the same "
               "keyframes fused once at the poses they had when first integrated, without any correction: where the two "
               "differ is what online surface correction changed.</p>\n";
  if (!gt_mesh.empty()) surfaceErrorTable(page, {&final_mesh, &uncorrected}, gt_mesh, in);
  render::RenderOptions oblique;
  oblique.width = options.image_width;
  oblique.height = options.image_height;
  oblique.up = upFromCameras(in.estimate ? in.estimate : in.odometry);
  // Both meshes are seen from the same viewpoints so that they compare.
  const Mesh& framing = final_mesh.mesh ? *final_mesh.mesh : *uncorrected.mesh;
  oblique.view = render::autoView(framing, oblique);
  const render::RenderOptions top = topViewOptions(framing, oblique);
  page.body << "<p>Up is the cameras' mean up direction (" << number(oblique.up.x(), 2) << ", " << number(oblique.up.y(), 2)
            << ", " << number(oblique.up.z(), 2) << "); back faces are culled, so walls facing away are see-through.</p>\n";
  for (const MeshFile* f : {&final_mesh, &uncorrected}) {
    if (!f->mesh) continue;
    const std::pair<const render::RenderOptions*, const char*> views[] = {{&oblique, "oblique"}, {&top, "from above"}};
    for (const auto& [view, label] : views) {
      const cv::Mat image = render::renderMesh(*f->mesh, *view);
      page.body << "<figure>" << inlinePngImage(image, f->name + ", " + label) << "<figcaption>" << escapeHtml(f->name)
                << ", " << label << " (" << escapeHtml(f->note) << ")</figcaption></figure>\n";
      ++page.images;
    }
  }
}

}  // namespace rekon::report
