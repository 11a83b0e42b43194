// granular-render — renders a JSON scene description through core/ (no USD needed).
//
//   granular-render SCENE.json -o OUT.exr [--png OUT.png] [--spp N] [--width W]
//                   [--height H] [--seed S] [--threads T] [--exposure E] [--quiet]
//                   [--technique ept|ept+vpt|hybrid] [--roulette P_a] [--lod L] [--stats-json FILE]
//                   [--no-motion-blur]
//
// --no-motion-blur renders the frame's instant, as the render setting "motion_blur": false
// (and `granular render --no-motion-blur`): the camera's shutter closed, moving grains and
// meshes still.
//
// --stats-json writes one JSON object: build_s, render_s, spp, technique, pa,
// lod_fraction, has_media, nonfinite_samples (samples dropped as NaN/Inf), nonfinite_values
// (NaN/Inf in the image's colour and AOV channels; Z is +inf where nothing was hit, by
// design, and not counted) and mean (the image's mean RGB over finite values).
//
// Exit status: 0 on success, 2 on bad input (one line naming object and attribute),
// 1 on any other failure. No partial output file is left behind.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "core/error.h"
#include "core/image_io.h"
#include "core/render.h"
#include "core/scene.h"
#include "core/scene_io.h"

using namespace granular;

namespace {

void usage() {
  std::fprintf(stderr,
               "usage: granular-render SCENE.json -o OUT.exr [--png OUT.png] [--spp N] [--width W] [--height H]\n"
               "                       [--seed S] [--threads T] [--exposure E] [--quiet]\n"
               "                       [--technique ept|ept+vpt|hybrid] [--roulette P_a (negative: tuned)]\n"
               "                       [--lod L (default 0.5; 0: off)] [--stats-json FILE]\n"
               "                       [--no-motion-blur (the frame's instant: the camera's shutter closed, moving\n"
               "                        grains and meshes still, as the render setting \"motion_blur\": false)]\n");
}

long parseInt(const char* flag, const char* v, long lo, long hi) {
  char* end = nullptr;
  long x = std::strtol(v, &end, 10);
  if (!end || *end || x < lo || x > hi) throw InputError("command line", flag, str("'", v, "' is not an integer in [", lo, ", ", hi, "]"));
  return x;
}

}  // namespace

int main(int argc, char** argv) {
  std::string scenePath, out, png;
  long spp = -1, width = -1, height = -1, threads = -1;
  long long seed = -1;
  float exposure = 0;
  bool quiet = false, motionBlur = true;
  std::string technique, statsPath;
  float roulette = 0, lod = -1;
  return runTool([&] {
    for (int i = 1; i < argc; ++i) {
      std::string a = argv[i];
      auto next = [&]() -> const char* {
        if (i + 1 >= argc) throw InputError("command line", a, "needs a value");
        return argv[++i];
      };
      if (a == "-o" || a == "--output") out = next();
      else if (a == "--png") png = next();
      else if (a == "--spp") spp = parseInt("--spp", next(), 1, 1000000);
      else if (a == "--width") width = parseInt("--width", next(), 1, 32768);
      else if (a == "--height") height = parseInt("--height", next(), 1, 32768);
      else if (a == "--seed") seed = parseInt("--seed", next(), 0, 0x7fffffffL);
      else if (a == "--threads") threads = parseInt("--threads", next(), 0, 1024);
      else if (a == "--exposure") exposure = std::strtof(next(), nullptr);
      else if (a == "--quiet") quiet = true;
      else if (a == "--no-motion-blur") motionBlur = false;
      else if (a == "--technique") technique = next();
      else if (a == "--lod") lod = std::strtof(next(), nullptr);
      else if (a == "--stats-json") statsPath = next();
      else if (a == "--roulette") roulette = std::strtof(next(), nullptr);
      else if (a == "-h" || a == "--help") { usage(); return 0; }
      else if (!a.empty() && a[0] == '-') throw InputError("command line", a, "unknown option");
      else if (scenePath.empty()) scenePath = a;
      else throw InputError("command line", "", "more than one scene given");
    }
    if (scenePath.empty() || out.empty()) { usage(); return 2; }

    SceneDesc desc = loadSceneJson(scenePath);
    if (spp > 0) desc.settings.spp = int(spp);
    if (width > 0) desc.settings.width = int(width);
    if (height > 0) desc.settings.height = int(height);
    if (seed >= 0) desc.settings.seed = uint64_t(seed);
    if (threads >= 0) desc.settings.threads = int(threads);
    if (!technique.empty()) desc.settings.technique = techniqueFromName(technique, "command line --technique");
    if (roulette != 0) desc.settings.roulette = roulette;
    if (lod >= 0) desc.settings.lod = lod;
    if (!motionBlur) stillFrame(desc);  // as loadSceneJson reads "motion_blur": false

    auto scene = Scene::build(desc);
    if (!quiet) {
      std::fprintf(stderr, "scene built in %.2f s\n", scene->buildSeconds());
      if (!scene->widenedSunsWarning().empty())
        std::fprintf(stderr, "warning: %s\n", scene->widenedSunsWarning().c_str());
      for (const auto& a : scene->aggregates()) {
        const auto& s = a->stats();
        std::fprintf(stderr, "  aggregate %s: ~%.3g grains, %lld cells (%lld inside, %lld partial), %.1f MiB, setup %.2f s\n",
                     a->name().c_str(), s.approxGrains, (long long)s.cells, (long long)s.insideCells,
                     (long long)s.partialCells, s.memoryBytes / 1048576.0, s.setupSeconds);
      }
    }
    Renderer renderer(*scene);
    double renderSeconds = 0;
    renderer.render(1, [&](const RenderProgress& p) {
      renderSeconds = p.seconds;
      if (quiet) return;
      std::fprintf(stderr, "\r  %ld/%ld spp  %.1f s", p.samplesDone, p.samplesTarget, p.seconds);
      if (p.samplesDone == p.samplesTarget) std::fprintf(stderr, "\n");
    });
    Image img = renderer.film().toImage();
    if (!quiet && scene->hasMedia()) {
      const RouletteTuning& rt = renderer.roulette();
      std::fprintf(stderr, "  technique %s, bundles of %d, P_a %.3f", techniqueName(scene->settings().technique),
                   renderer.bundleSize(), rt.pa);
      if (rt.pixels)
        std::fprintf(stderr, " (pre-render of %d pixels: V_L %.3g, V_H %.3g, t_L %.3g, t_H %.3g)", rt.pixels, rt.VL,
                     rt.VH, rt.tL, rt.tH);
      // Mean of each transport's AOV over the image: what each part contributes.
      const char* names[4] = {"ept.R", "vpt.R", "da.R", "ppt.R"};
      double part[4] = {0, 0, 0, 0};
      for (int t = 0; t < 4; ++t) {
        int c0 = img.channelIndex(names[t]);
        for (int y = 0; y < img.height; ++y)
          for (int x = 0; x < img.width; ++x) part[t] += luminance(Vec3(img.at(x, y)[c0], img.at(x, y)[c0 + 1], img.at(x, y)[c0 + 2]));
      }
      double n = double(img.width) * img.height;
      std::fprintf(stderr, "\n  mean luminance by transport: EPT %.4g, PPT %.4g, VPT %.4g, DA %.4g; level of detail: %.1f%% of paths entered a medium directly\n",
                   part[0] / n, part[3] / n, part[1] / n, part[2] / n, 100.0 * renderer.shortcutFraction());
    }
    if (!quiet && !scene->lightPicksText().empty())
      std::fprintf(stderr, "  light sampling picks: %s\n", scene->lightPicksText().c_str());
    if (!quiet && !scene->iesProfilesText().empty())
      std::fprintf(stderr, "  IES profiles: %s\n", scene->iesProfilesText().c_str());
    writeImage(out, img);
    if (!png.empty()) writePngSrgb(png, img, exposure);
    if (!quiet) std::fprintf(stderr, "wrote %s%s%s\n", out.c_str(), png.empty() ? "" : " and ", png.c_str());
    if (!statsPath.empty()) {
      // Timings for benchmarks: scene build (BVHs, tiles, TT) and rendering (pre-render included).
      FILE* f = std::fopen(statsPath.c_str(), "w");
      if (!f) throw std::runtime_error("cannot write " + statsPath);
      // Robustness counters: samples dropped as non-finite, and non-finite values in the
      // colour and AOV channels of the image (Z is +inf where nothing was hit, by design).
      // The mean is over finite values, so that the file stays valid JSON.
      const int zc = img.channelIndex("Z");
      long nonFiniteValues = 0;
      double sum[3] = {0, 0, 0};
      for (int y = 0; y < img.height; ++y)
        for (int x = 0; x < img.width; ++x)
          for (int c = 0; c < img.numChannels(); ++c) {
            float v = img.at(x, y)[c];
            if (!std::isfinite(v)) nonFiniteValues += c != zc;
            else if (c < 3) sum[c] += v;
          }
      const double n = double(img.width) * img.height;
      std::fprintf(f,
                   "{\"build_s\": %.6f, \"render_s\": %.6f, \"spp\": %ld, \"technique\": \"%s\", \"pa\": %.6f, "
                   "\"lod_fraction\": %.6f, \"has_media\": %s, \"nonfinite_samples\": %ld, \"nonfinite_values\": %ld, "
                   "\"lost_paths\": %ld, \"mean\": [%.6g, %.6g, %.6g]}\n",
                   scene->buildSeconds(), renderSeconds, renderer.samplesPerPixel(),
                   techniqueName(scene->settings().technique), renderer.roulette().pa, renderer.shortcutFraction(), scene->hasMedia() ? "true" : "false",
                   renderer.nonFiniteSamples(), nonFiniteValues, renderer.lostPaths(), sum[0] / n, sum[1] / n, sum[2] / n);
      std::fclose(f);
    }
    return 0;
  });
}
