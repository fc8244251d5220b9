// Camera views shaded from a database (tools/scene_views.h): the glossy image is shaded with each
// pixel's own reflection direction (it was the irradiance image), and a view whose scene is not
// the database's is refused; and the tools' output helpers (tools/outputs.h, tools/args.h).
#include "tools/scene_views.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "pbgi/shade.h"
#include "tests/common/scratch_dir.h"
#include "tools/args.h"
#include "tools/outputs.h"
#include "tools/progress.h"

namespace pbgi::tools {
namespace {

struct Built {
  std::shared_ptr<const Scene> scene;
  std::string db_path;
};

Built BuildScene(const testing_common::ScratchDir& dir, const std::string& name, uint64_t seed) {
  Built b;
  auto scene = LoadScene(name, seed, 0);
  EXPECT_TRUE(scene.ok()) << scene.status();
  b.scene = *scene;
  SamplerOptions sampler;
  sampler.count = 20000;
  sampler.seed = seed;
  auto src = MakeSceneSurfelSource(b.scene, sampler);
  EXPECT_TRUE(src.ok());
  BuildOptions bo;
  bo.memory_bytes = 64 << 20;
  bo.provenance = SceneFingerprint(*b.scene, seed, 0, UpAxis::kZ);
  b.db_path = dir.Sub(name + ".pbgi");
  auto st = BuildDatabase(**src, b.db_path, bo);
  EXPECT_TRUE(st.ok()) << st.status();
  return b;
}

TEST(SceneViewsTest, GlossyViewUsesEachPixelsReflectionDirection) {
  const testing_common::ScratchDir dir;
  const Built b = BuildScene(dir, "cornell", 1);
  auto db = Database::Open(b.db_path);
  ASSERT_TRUE(db.ok()) << db.status();
  auto tracer = Tracer::Create(*b.scene);
  ASSERT_TRUE(tracer.ok());
  const Camera camera = DefaultCamera(*b.scene, 24, 16);
  ShadeOptions so;
  so.threads = 2;
  so.cut.cosine_weighted = false;
  so.raster.lobe = GlossyLobe::kPhong;
  so.raster.phong_exponent = 32.0f;
  auto view = RenderView(**tracer, **db, camera, so);
  ASSERT_TRUE(view.ok()) << view.status();

  // The same receivers shaded directly: with the mirror direction of the camera ray, and with
  // the normal (what a lobe without a reflection would use).
  const std::vector<CameraHit> hits = (*tracer)->TraceCamera(camera);
  std::vector<ShadeReceiver> mirror, normal;
  std::vector<size_t> pixel;
  for (size_t p = 0; p < hits.size(); ++p) {
    if (!hits[p].hit) continue;
    const glm::vec3 d = camera.Direction(float(p % 24) + 0.5f, float(p / 24) + 0.5f);
    glm::vec3 n = hits[p].normal;
    if (glm::dot(n, d) > 0) n = -n;
    const glm::vec3 at = hits[p].position + (*tracer)->epsilon() * n;
    mirror.push_back({at, n, glm::reflect(d, n)});
    normal.push_back({at, n, n});
    pixel.push_back(p);
  }
  ASSERT_GT(pixel.size(), 200u);
  std::vector<ShadeResult> rm(mirror.size()), rn(normal.size());
  ASSERT_TRUE(ShadeBatch(**db, mirror, so, absl::MakeSpan(rm)).ok());
  ASSERT_TRUE(ShadeBatch(**db, normal, so, absl::MakeSpan(rn)).ok());
  size_t differ = 0;
  for (size_t i = 0; i < pixel.size(); ++i) {
    const glm::vec3 got = view->glossy.pixels[pixel[i]];
    ASSERT_EQ(got, rm[i].glossy) << "pixel " << pixel[i];
    if (glm::length(rm[i].glossy - rn[i].glossy) > 1e-3f * (1.0f + glm::length(rn[i].glossy))) {
      ++differ;
    }
    // Not the irradiance, which is what the glossy mode used to write.
    ASSERT_NE(got, rm[i].irradiance);
  }
  EXPECT_GT(differ, pixel.size() / 2) << "the reflection direction barely matters?";
}

// Composing runs on all cores (it was a serial loop of shadow rays), after the camera hits are
// dropped and on images made after shading (memory): every pixel still gets the tracer's direct
// light for its own receiver, material and pixel, the shaded values of its receiver, and the
// sky where nothing was hit.
TEST(SceneViewsTest, ComposedPixelsAreEachPixelsOwnDirectLightAndShading) {
  const testing_common::ScratchDir dir;
  const Built b = BuildScene(dir, "city", 1);
  auto db = Database::Open(b.db_path);
  ASSERT_TRUE(db.ok()) << db.status();
  auto tracer = Tracer::Create(*b.scene);
  ASSERT_TRUE(tracer.ok());
  const Camera camera = DefaultCamera(*b.scene, 96, 64);
  ShadeOptions so;
  so.threads = 2;
  so.raster.compute_radiance = true;
  auto view = RenderView(**tracer, **db, camera, so);
  ASSERT_TRUE(view.ok()) << view.status();
  EXPECT_GE(view->compose_seconds, 0.0);
  // No lobe asked for: no glossy image is held.
  EXPECT_EQ(view->glossy.width, 0);
  EXPECT_TRUE(view->glossy.pixels.empty());
  EXPECT_EQ(view->direct.pixels.size(), size_t(96) * 64);

  const CameraReceivers cr = MakeCameraReceivers(**tracer, camera);
  ASSERT_EQ(view->receivers, cr.receivers.size());
  ASSERT_GT(cr.receivers.size(), 3000u);
  std::vector<ShadeResult> shaded(cr.shade.size());
  ASSERT_TRUE(ShadeBatch(**db, cr.shade, so, absl::MakeSpan(shaded)).ok());
  for (size_t i = 0; i < cr.receivers.size(); ++i) {
    const uint32_t p = cr.pixel_of[i];
    const glm::vec3 direct = (*tracer)->SurfaceRadiance(cr.receivers[i].position,
                                                        cr.receivers[i].normal, cr.surface[i], p);
    ASSERT_EQ(view->direct.pixels[p], direct) << "pixel " << p;
    ASSERT_EQ(view->occlusion.pixels[p],
              glm::vec3(1.0f - std::clamp(shaded[i].occlusion, 0.0f, 1.0f)))
        << "pixel " << p;
    ASSERT_EQ(view->composite.pixels[p], direct + view->indirect.pixels[p]) << "pixel " << p;
  }
  size_t sky = 0;
  for (size_t p = 0; p < cr.hits.size(); ++p) {
    if (cr.hits[p].hit) continue;
    ++sky;
    ASSERT_EQ(view->composite.pixels[p], b.scene->lights.sky) << "pixel " << p;
    ASSERT_EQ(view->direct.pixels[p], b.scene->lights.sky) << "pixel " << p;
    ASSERT_EQ(view->occlusion.pixels[p], glm::vec3(1.0f)) << "pixel " << p;
  }
  EXPECT_GT(sky, 200u) << "the view should show some sky";
  EXPECT_EQ(sky + cr.receivers.size(), cr.hits.size());
}

// A caller may close the database once the view is shaded (the demo does, so that its page
// cache is not held beside the images): the callback runs once, the database is not used after
// it, and the images are those of a view whose database stayed open.
TEST(SceneViewsTest, TheDatabaseMayCloseBeforeTheViewIsComposed) {
  const testing_common::ScratchDir dir;
  const Built b = BuildScene(dir, "city", 1);
  auto tracer = Tracer::Create(*b.scene);
  ASSERT_TRUE(tracer.ok());
  const Camera camera = DefaultCamera(*b.scene, 64, 48);
  ShadeOptions so;
  so.threads = 2;
  so.raster.compute_radiance = true;
  so.mode = ShadeMode::kShared;
  auto open = Database::Open(b.db_path);
  ASSERT_TRUE(open.ok()) << open.status();
  auto kept = RenderView(**tracer, **open, camera, so);
  ASSERT_TRUE(kept.ok()) << kept.status();

  auto closing = Database::Open(b.db_path);
  ASSERT_TRUE(closing.ok()) << closing.status();
  std::unique_ptr<Database> db = std::move(closing).value();
  int calls = 0;
  auto closed = RenderView(**tracer, *db, camera, so, [&]() {
    ++calls;
    db.reset();
  });
  ASSERT_TRUE(closed.ok()) << closed.status();
  EXPECT_EQ(calls, 1);
  EXPECT_EQ(db, nullptr);
  EXPECT_EQ(closed->receivers, kept->receivers);
  EXPECT_EQ(closed->composite.pixels, kept->composite.pixels);
  EXPECT_EQ(closed->indirect.pixels, kept->indirect.pixels);
  EXPECT_EQ(closed->occlusion.pixels, kept->occlusion.pixels);
  EXPECT_EQ(closed->direct.pixels, kept->direct.pixels);
}

TEST(SceneViewsTest, AViewOfAnotherSceneIsRefused) {
  const testing_common::ScratchDir dir;
  const Built b = BuildScene(dir, "cornell", 3);
  auto store = PageStore::Open(b.db_path);
  ASSERT_TRUE(store.ok());
  const StoreMeta& meta = (*store)->meta();
  std::string warning;
  EXPECT_TRUE(CheckSceneMatchesDatabase(*b.scene, SceneFingerprint(*b.scene, 3, 0, UpAxis::kZ),
                                        meta, b.db_path, &warning)
                  .ok());
  auto city = LoadScene("city", 1, 0);
  ASSERT_TRUE(city.ok());
  absl::Status s = CheckSceneMatchesDatabase(**city, SceneFingerprint(**city, 1, 0, UpAxis::kZ),
                                             meta, b.db_path, &warning);
  EXPECT_EQ(s.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(s.message().find("built from scene 'cornell' seed 3"), std::string::npos) << s;
  EXPECT_NE(s.message().find("--scene cornell --seed 3"), std::string::npos) << s;
  // The same scene with another seed (the blocks turn): another geometry.
  auto other = LoadScene("cornell", 4, 0);
  ASSERT_TRUE(other.ok());
  EXPECT_FALSE(CheckSceneMatchesDatabase(**other, SceneFingerprint(**other, 4, 0, UpAxis::kZ), meta,
                                         b.db_path, &warning)
                   .ok());
  // Without a fingerprint, bounds that do not fit warn.
  StoreMeta bare = meta;
  for (auto it = bare.stats.begin(); it != bare.stats.end();) {
    it = it->first.rfind("scene.", 0) == 0 ? bare.stats.erase(it) : std::next(it);
  }
  EXPECT_TRUE(CheckSceneMatchesDatabase(**city, SceneFingerprint(**city, 1, 0, UpAxis::kZ), bare,
                                        b.db_path, &warning)
                  .ok());
  EXPECT_NE(warning.find("do not fit"), std::string::npos) << warning;
  EXPECT_TRUE(CheckSceneMatchesDatabase(*b.scene, SceneFingerprint(*b.scene, 3, 0, UpAxis::kZ),
                                        bare, b.db_path, &warning)
                  .ok());
  EXPECT_EQ(warning, "");
}

// Regression (mesh_fingerprint_names_up): a mesh's fingerprint was that of a procedural scene
// (seed, no up axis), so a view with the wrong --up was refused with two identical descriptions.
TEST(SceneViewsTest, MeshFingerprintRecordsUpAndOrientAndSaysWhatDiffers) {
  const testing_common::ScratchDir dir;
  const std::string path = dir.Sub("wedge.obj");
  std::ofstream(path) << "v 0 0 0\nv 2 0 0\nv 0 1 0\nv 0 0 3\nf 1 2 3\nf 1 2 4\nf 1 4 3\n"
                         "f 2 3 4\n";
  auto z = LoadScene(path, 1, 0, UpAxis::kZ);
  auto y = LoadScene(path, 1, 0, UpAxis::kY);
  ASSERT_TRUE(z.ok() && y.ok()) << z.status() << y.status();
  // --up y: the file's y (extent 1) is up, its z (extent 3) points to -y.
  EXPECT_NEAR((*y)->ComputeBounds().hi.z, 1.0f, 1e-6f);
  EXPECT_NEAR((*y)->ComputeBounds().lo.y, -3.0f, 1e-6f);
  auto fz = SceneFingerprint(**z, 1, 0, UpAxis::kZ);
  auto fy = SceneFingerprint(**y, 1, 0, UpAxis::kY);
  EXPECT_EQ(fz.count("scene.seed"), 0u);
  EXPECT_EQ(fz["scene.up"], "z");
  EXPECT_EQ(fy["scene.up"], "y");
  EXPECT_EQ(fz["scene.orient"], "auto");
  StoreMeta meta;
  meta.stats = fy;
  meta.stats["scene.file"] = path;
  std::string warning;
  absl::Status s = CheckSceneMatchesDatabase(**z, fz, meta, "db", &warning);
  EXPECT_EQ(s.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(s.message().find("up: database y, view z"), std::string::npos) << s;
  EXPECT_NE(s.message().find("--scene " + path + " --up y"), std::string::npos) << s;
  EXPECT_TRUE(CheckSceneMatchesDatabase(**y, fy, meta, "db", &warning).ok());
  // Imported with --orient none (the wedge's first face is wound inward): named too.
  auto raw = LoadScene(path, 1, 0, UpAxis::kY, /*orient=*/false);
  ASSERT_TRUE(raw.ok());
  meta.stats = SceneFingerprint(**raw, 1, 0, UpAxis::kY, false);
  s = CheckSceneMatchesDatabase(**y, fy, meta, "db", &warning);
  EXPECT_NE(s.message().find("orient: database none, view auto"), std::string::npos) << s;
  EXPECT_NE(s.message().find("--orient none"), std::string::npos) << s;
}

// A mesh file brings no lights: without --sun or --sky it is lit by a white sky (as `pbgi
// import` lights it); a procedural scene keeps its own unless the flags replace them.
TEST(SceneViewsTest, MeshFilesAreLitAsImportLightsThem) {
  const testing_common::ScratchDir dir;
  const std::string path = dir.Sub("wedge.obj");
  std::ofstream(path) << "v 0 0 0\nv 2 0 0\nv 0 1 0\nv 0 0 3\nf 1 2 3\nf 1 2 4\nf 1 4 3\n"
                         "f 2 3 4\n";
  auto plain = LoadScene(path, 1, 0);
  ASSERT_TRUE(plain.ok()) << plain.status();
  EXPECT_EQ((*plain)->lights.sky, glm::vec3(0.0f));  // what eval compared as zeros
  auto lit = LoadLitScene(path, 1, 0, UpAxis::kZ, true, LightFlags{}, "test");
  ASSERT_TRUE(lit.ok()) << lit.status();
  EXPECT_EQ((*lit)->lights.sky, glm::vec3(1.0f));
  EXPECT_FALSE((*lit)->lights.has_sun);
  EXPECT_EQ((*lit)->lights.sky_rays, 8);
  LightFlags sun;
  sun.sun = "0,0,2,3,2,1";
  sun.sky_rays = 4;
  auto sunny = LoadLitScene(path, 1, 0, UpAxis::kZ, true, sun, "test");
  ASSERT_TRUE(sunny.ok()) << sunny.status();
  EXPECT_TRUE((*sunny)->lights.has_sun);
  EXPECT_EQ((*sunny)->lights.sun.direction, glm::vec3(0.0f, 0.0f, 1.0f));
  EXPECT_EQ((*sunny)->lights.sun.radiance, glm::vec3(3.0f, 2.0f, 1.0f));
  EXPECT_EQ((*sunny)->lights.sky, glm::vec3(0.0f));  // only what is given
  EXPECT_EQ((*sunny)->lights.sky_rays, 4);
  // A database's recorded lights (pbgi import --sun ..., eval --view's build) light a mesh
  // that no flag lights, as `pbgi shade` reads them; flags still win.
  const std::map<std::string, std::string> recorded = {
      {"light.sun", "0,0,1,2,2,2"}, {"light.sky", "0.25,0.5,0.75"}, {"light.sky_rays", "4"}};
  auto rec = LoadLitScene(path, 1, 0, UpAxis::kZ, true, LightFlags{}, "test", nullptr, &recorded);
  ASSERT_TRUE(rec.ok()) << rec.status();
  EXPECT_EQ((*rec)->lights.sky, glm::vec3(0.25f, 0.5f, 0.75f));
  EXPECT_TRUE((*rec)->lights.has_sun);
  EXPECT_EQ((*rec)->lights.sky_rays, 4);
  auto flagged = LoadLitScene(path, 1, 0, UpAxis::kZ, true, sun, "test", nullptr, &recorded);
  ASSERT_TRUE(flagged.ok());
  EXPECT_EQ((*flagged)->lights.sky, glm::vec3(0.0f));
  EXPECT_EQ((*flagged)->lights.sun.radiance, glm::vec3(3.0f, 2.0f, 1.0f));
  // A procedural scene keeps its lights without flags, and takes what the flags give.
  auto city = LoadScene("city", 1, 0);
  auto city_lit = LoadLitScene("city", 1, 0, UpAxis::kZ, true, LightFlags{}, "test");
  ASSERT_TRUE(city.ok() && city_lit.ok());
  EXPECT_EQ((*city_lit)->lights.sky, (*city)->lights.sky);
  EXPECT_EQ((*city_lit)->lights.sun.direction, (*city)->lights.sun.direction);
  EXPECT_EQ((*city_lit)->lights.sky_rays, (*city)->lights.sky_rays);
  LightFlags grey;
  grey.sky = "0.5,0.5,0.5";
  auto city_grey = LoadLitScene("city", 1, 0, UpAxis::kZ, true, grey, "test");
  ASSERT_TRUE(city_grey.ok());
  EXPECT_EQ((*city_grey)->lights.sky, glm::vec3(0.5f));
  EXPECT_TRUE((*city_grey)->lights.has_sun);
  // Malformed flags are refused, naming the flag.
  LightFlags bad;
  bad.sun = "0,0,0";
  auto s = LoadLitScene(path, 1, 0, UpAxis::kZ, true, bad, "test");
  EXPECT_EQ(s.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.status().message().find("--sun: zero direction"), std::string::npos) << s.status();
  bad = LightFlags{};
  bad.sky = "1,2";
  s = LoadLitScene(path, 1, 0, UpAxis::kZ, true, bad, "test");
  EXPECT_NE(s.status().message().find("--sky"), std::string::npos) << s.status();
}

TEST(SceneViewsTest, YUpMeshesTurnToZUp) {
  Scene s;
  s.meshes.push_back(Mesh{{{0, 0, 0}, {1, 0, 0}, {0, 2, 0}}, {{0, 1, 2}}, {0}});
  s.instances.push_back(Instance{});
  s.materials.push_back(Material{});
  RotateYUpToZUp(&s);
  const Bounds b = s.ComputeBounds();
  EXPECT_NEAR(b.hi.z, 2.0f, 1e-6f);  // what was up (y) is up (z)
  EXPECT_NEAR(b.hi.y, 0.0f, 1e-6f);
  EXPECT_NEAR(b.lo.y, 0.0f, 1e-6f);
}

TEST(OutputsTest, OutputsThatAreInputsAreRefused) {
  const testing_common::ScratchDir dir;
  const std::string a = dir.Sub("a.ply");
  std::ofstream(a) << "x";
  EXPECT_FALSE(CheckOutputsAreNotInputs({a}, {a}).ok());
  EXPECT_FALSE(CheckOutputsAreNotInputs({a}, {dir.Sub("./sub/../a.ply")}).ok());
  std::filesystem::create_symlink(a, dir.Sub("link.ply"));
  EXPECT_FALSE(CheckOutputsAreNotInputs({dir.Sub("link.ply")}, {a}).ok());
  std::filesystem::create_hard_link(a, dir.Sub("hard.ply"));
  EXPECT_FALSE(CheckOutputsAreNotInputs({dir.Sub("hard.ply")}, {a}).ok());
  EXPECT_FALSE(CheckOutputsAreNotInputs({}, {dir.Sub("b"), dir.Sub("b")}).ok());
  EXPECT_TRUE(CheckOutputsAreNotInputs({a}, {dir.Sub("b.ply"), ""}).ok());
}

TEST(OutputsTest, OutputFileReplacesOnlyOnCommit) {
  const testing_common::ScratchDir dir;
  const std::string p = dir.Sub("out.json");
  std::ofstream(p) << "old";
  {
    OutputFile f(p);
    std::ofstream(f.tmp_path()) << "half";
  }  // abandoned
  EXPECT_FALSE(std::filesystem::exists(dir.Sub("out.json.tmp-" + std::to_string(getpid()))));
  std::ifstream in(p);
  std::string got;
  in >> got;
  EXPECT_EQ(got, "old");
  ASSERT_TRUE(WriteFileAtomically(p, "new").ok());
  std::ifstream in2(p);
  in2 >> got;
  EXPECT_EQ(got, "new");
}

TEST(ArgsTest, CountsTakeSuffixesAndExponents) {
  EXPECT_EQ(*ParseCount("50k"), 50000);
  EXPECT_EQ(*ParseCount("2M"), 2000000);
  EXPECT_EQ(*ParseCount("1e8"), 100000000);
  EXPECT_EQ(*ParseCount("2.5M"), 2500000);
  EXPECT_EQ(*ParseCount("1G"), 1000000000);
  EXPECT_EQ(*ParseCount("12"), 12);
  for (const char* bad : {"", "k", "lots", "-5", "1.5", "1e30", "nan", "inf"}) {
    EXPECT_FALSE(ParseCount(bad).ok()) << bad;
  }
  EXPECT_GE(ResolveThreads(0), 1);
  EXPECT_EQ(ResolveThreads(3), 3);
}

TEST(ProgressTest, LinesSayDoneTotalRateAndEta) {
  double now = 100.0;
  char* buf = nullptr;
  size_t len = 0;
  std::FILE* out = open_memstream(&buf, &len);
  {
    Progress p(
        "shade", "receivers", 1000, Progress::Style::kLines, 2.0, [&] { return now; }, out);
    now = 101.0;
    p.Update(100);  // within the first interval: nothing yet
    now = 104.0;
    p.Update(400);  // 100/s: 600 left, ETA 6 s
    now = 105.0;
    p.Update(500);  // within the interval of the last line
    now = 110.0;
    p.Finish(1000, "done");
  }
  std::fclose(out);
  const std::string text(buf, len);
  std::free(buf);
  EXPECT_EQ(text,
            "shade: 400 / 1000 receivers (40.0%), 100 receivers/s, ETA 0:06, 0:04 elapsed\n"
            "shade: 1000 receivers in 10.00 s (100 receivers/s), done\n");
  EXPECT_EQ(ShortCount(1234567), "1.23M");
  EXPECT_EQ(Clocklike(3725), "1:02:05");
}

}  // namespace
}  // namespace pbgi::tools
