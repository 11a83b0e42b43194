// Renderer::progressSamples: progress within a pass, readable from another thread.
#include <gtest/gtest.h>

#include <atomic>
#include <thread>
#include <vector>

#include "render.h"
#include "scene.h"
#include "shapes.h"

using namespace granular;

TEST(RenderProgress, GrowsWithinPassesAndEndsAtTheSampleCount) {
  SceneDesc d;
  d.settings.width = 64;
  d.settings.height = 48;
  d.settings.spp = 6;
  d.settings.technique = Technique::Ept;
  MeshDesc m;
  m.name = "ball";
  m.mesh = makeIcosphere(2);
  m.xf = Transform::translate(Vec3(0, 0, -4));
  d.meshes.push_back(m);
  LightDesc sun;
  sun.name = "sun";
  d.lights.push_back(sun);
  auto scene = Scene::build(d);
  Renderer r(*scene);
  EXPECT_EQ(r.progressSamples(), 0.0);

  std::atomic<bool> stop{false}, polling{false};
  std::vector<double> seen;
  std::thread poller([&] {
    while (!stop) {
      seen.push_back(r.progressSamples());
      polling = true;
      std::this_thread::yield();
    }
  });
  // On a loaded machine the render could end before the poller first runs.
  while (!polling) std::this_thread::yield();
  std::vector<long> atPass;
  std::vector<double> progressAtPass;
  ASSERT_TRUE(r.render(2, [&](const RenderProgress& p) {
    atPass.push_back(p.samplesDone);
    progressAtPass.push_back(r.progressSamples());
  }));
  stop = true;
  poller.join();
  EXPECT_EQ(atPass, (std::vector<long>{2, 4, 6}));
  EXPECT_EQ(progressAtPass, (std::vector<double>{2, 4, 6}));
  EXPECT_EQ(r.progressSamples(), 6.0);
  ASSERT_FALSE(seen.empty());
  for (size_t i = 0; i < seen.size(); ++i) {
    EXPECT_GE(seen[i], 0.0);
    EXPECT_LE(seen[i], 6.0);
    if (i) EXPECT_GE(seen[i], seen[i - 1]) << "progress went back at " << i;
  }
}
