// The map on the bus (issue 17), end to end: `rekon run` on the synthetic
// room with `rekon listen --mesh` beside it, one listener from the start and
// one started late (it asks for a full snapshot). Both assemble the mapper's
// mesh.ply: the same vertices within the quantum and the same triangles.
// Every process runs under a timeout in a private network namespace.
#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <string>
#include <tuple>

#include "rekon/common/mesh.hpp"
#include "test_support.hpp"

namespace {

using rekon::test::runCommand;

std::string bin() { return rekon::test::binDir(); }
using rekon::test::inNetns;

// Quanta per metre as the mapper's encoder computes them (volume.voxel_size
// 0.01 / 1024 per quantum): float vertices can sit exactly half way between
// two quanta, so the test must round the same product the same way.
const double kPerMetre = 1.0 / (0.01 / 1024);

using Quanta = std::set<std::tuple<long long, long long, long long>>;

// Vertices by their quanta: the mapper's coincident vertices (a voxel at
// distance exactly 0 puts several on one point) count once, as a listener
// keeps them.
Quanta quantaOf(const rekon::Mesh& mesh) {
  Quanta out;
  for (const auto& v : mesh.vertices) {
    out.insert({std::llround(v.x() * kPerMetre), std::llround(v.y() * kPerMetre), std::llround(v.z() * kPerMetre)});
  }
  return out;
}

void expectSameSurface(const std::string& assembled_path, const rekon::Mesh& reference, const std::string& what) {
  const rekon::Mesh assembled = rekon::readPly(assembled_path);
  const Quanta a = quantaOf(assembled), r = quantaOf(reference);
  EXPECT_EQ(assembled.vertices.size(), r.size()) << what;
  EXPECT_EQ(assembled.triangles.size(), reference.triangles.size()) << what;
  size_t missing = 0;
  for (const auto& q : r) missing += a.count(q) ? 0 : 1;
  EXPECT_EQ(missing, 0u) << what << ": vertices of mesh.ply not within the quantum of the assembled mesh";
  EXPECT_EQ(a.size(), r.size()) << what;
}

}  // namespace

TEST(MeshOnTheBus, ListenersFromTheStartAndLateAssembleTheMapperMesh) {
  rekon::test::TempDir dir;
  std::string out;
  ASSERT_EQ(runCommand("timeout 120 " + bin() + "/rekon synth --scene room --frames 120 --out " + (dir / "room"), &out), 0) << out;
  // The player at the recorded rate (4 s of frames), so the late listener
  // (2.5 s in) joins while the mapper is mapping.
  const std::string listen = "timeout 200 " + bin() + "/rekon listen --mesh ";
  const std::string script =
      listen + (dir / "early.ply") + " --out " + (dir / "early") + " > " + (dir / "early.log") + " 2>&1 & early=$!; " +
      "sleep 0.5; timeout 240 " + bin() + "/rekon run --dataset " + (dir / "room") + " --out " + (dir / "run") +
      " --set player.rate=1.0 > " + (dir / "run.log") + " 2>&1 & run=$!; sleep 2.5; " + listen + (dir / "late.ply") +
      " --out " + (dir / "late") + " > " + (dir / "late.log") + " 2>&1 & late=$!; " +
      "wait $run; s=$?; wait $early; e=$?; wait $late; l=$?; echo run=$s early=$e late=$l; [ $s$e$l = 000 ]";
  const int rc = runCommand(inNetns() + " bash -c '" + script + "'", &out);
  ASSERT_EQ(rc, 0) << out << rekon::test::readText(dir / "run.log") << rekon::test::readText(dir / "early.log")
                   << rekon::test::readText(dir / "late.log");

  const rekon::Mesh reference = rekon::readPly(dir / "run/mesh.ply");
  ASSERT_GT(reference.triangles.size(), 10000u);  // the room: walls, floor and objects
  expectSameSurface(dir / "early.ply", reference, "listener from the start");
  expectSameSurface(dir / "late.ply", reference, "late listener");
  // The late one got a full snapshot in answer to its request.
  EXPECT_GT(rekon::test::jsonInt(rekon::test::readText(dir / "late/listener_stats.json"), "mesh_full_parts"), 0);
  const std::string stats = rekon::test::readText(dir / "run/mapper_stats.json");
  EXPECT_GE(rekon::test::jsonInt(stats, "mesh_full_snapshots"), 1);
  EXPECT_GT(rekon::test::jsonInt(stats, "mesh_updates"), 2);
}
