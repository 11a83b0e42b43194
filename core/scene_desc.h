// scene_desc.h — the plain scene description every front end produces.
//
// Contract: plain data, no renderer state. The JSON reader (io), the usd-core command
// line and the Hydra delegate all fill a SceneDesc; Scene::build() turns it into BVHs,
// distance fields, tiles and transport parameters. Units are the scene's own; angles in
// degrees; colours linear Rec.709. Conventions follow USD: cameras look down local -Z
// with +Y up, distant and rect lights emit along local -Z.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "math.h"
#include "mesh.h"
#include "shared_array.h"

namespace granular {

struct CameraDesc {
  Transform cameraToWorld;            // local -Z is the view direction
  float focalLength = 50.0f;          // same unit as the apertures (USD: tenths of scene unit / mm)
  float horizontalAperture = 36.0f;
  float verticalAperture = 24.0f;
  float horizontalApertureOffset = 0.0f;
  float verticalApertureOffset = 0.0f;
  float clipNear = 1e-4f;
  float clipFar = 1e30f;
  // Depth of field (thin lens): the lens radius and the distance of the plane in focus
  // along the view axis, both in scene units. lensRadius 0 is the pinhole. USD: radius =
  // focalLength / (2 fStop), the focal length in scene units (UsdGeomCamera stores tenths).
  float lensRadius = 0.0f;
  float focusDistance = 1.0f;
  // Motion blur: the shutter's interval in seconds relative to the frame's time (USD's
  // shutter:open and shutter:close are in time codes: divided by timeCodesPerSecond). Each
  // camera ray takes a time uniform in it; open == close: no blur. Moving grains
  // (InstancedGrainsDesc::velocities, angularVelocities) are placed at the ray's time.
  float shutterOpen = 0.0f;
  float shutterClose = 0.0f;
};

// The longest time from the frame's time a camera ray can have (0 without motion blur).
inline float motionSpan(const CameraDesc& c) {
  return c.shutterClose > c.shutterOpen ? std::max(std::fabs(c.shutterOpen), std::fabs(c.shutterClose)) : 0.0f;
}

// A thin lens's radius in scene units from UsdGeomCamera's focalLength (tenths of a scene
// unit, as its apertures) and fStop: focalLength / 10 / (2 fStop), as Hydra's HdCamera
// (focal length in scene units) gives it. fStop <= 0: a pinhole (0). Both front ends and
// JSON scenes use it, so one camera blurs alike everywhere.
inline float lensRadiusFromFStop(float focalLength, float fStop) {
  return fStop > 0 ? 0.05f * focalLength / fStop : 0.0f;
}
// No lens in air is faster than f/0.5 (N = 1 / (2 sin θ) with θ < 90°): below it the lens
// is wider than anything a camera can be (an fStop of 1e-15 made rays start 10^15 units
// away and aborted the render inside Embree).
constexpr float kFastestFStop = 0.5f;
// lensRadiusFromFStop for a user's value: InputError on object.attribute for an fStop that
// is not finite, negative, or in (0, kFastestFStop).
float checkedLensRadius(float focalLength, float fStop, const std::string& object, const std::string& attribute);

// A UsdUVTexture feeding one material input, looked up at the mesh's texture coordinates
// (TriangleMesh::uvs; USD's st, origin at the image's lower left) through OpenImageIO's
// TextureSystem (texture.h). value = texel × scale + bias per channel (r, g, b, a), the
// texel decoded from sRGB first where the colour space says so (rgb only, not alpha).
// The front ends take `file` from inputs:file (resolved), the rest from the shader's inputs
// of the same names; `source` is the shader's path, for messages.
enum class TextureWrap { UseMetadata, Black, Clamp, Repeat, Mirror };
// Auto: sRGB for 8-bit images, raw otherwise (UsdUVTexture's rule).
enum class TextureColorSpace { Auto, Raw, SRGB };

struct TextureDesc {
  std::string file;                   // empty: no texture (the material's constant applies)
  std::string source;                 // e.g. "/World/Looks/Ground/Diffuse"
  TextureWrap wrapS = TextureWrap::UseMetadata, wrapT = TextureWrap::UseMetadata;
  float scale[4] = {1, 1, 1, 1};
  float bias[4] = {0, 0, 0, 0};
  TextureColorSpace colorSpace = TextureColorSpace::Auto;
  int channel = -1;                   // -1: the rgb output; 0..3: the r, g, b or a output
  bool enabled() const { return !file.empty(); }
};

// DiffusionExit is internal: the lobe of light leaving a diffusing medium (diffusion.h).
enum class MaterialType { Lambert, Dielectric, DiffusionExit };

struct MaterialDesc {
  std::string name;
  MaterialType type = MaterialType::Lambert;
  Vec3 albedo{0.5f};       // Lambert reflectance (unused by Dielectric: colour comes from absorption)
  float ior = 1.5f;        // Dielectric index of refraction (1 = index-matched)
  // Dielectric Beer–Lambert absorption coefficient per unit length of the mesh's own
  // space. Grain prototypes are normalised to a unit bounding sphere, so for grains it is
  // the optical depth per grain radius, independent of the aggregate's grain size.
  Vec3 absorption{0.0f};
  Vec3 emission{0.0f};     // Lambert surfaces may emit (radiance)
  // Dielectric surface roughness in [0, 1]: GGX α = roughness² (microfacet.h); 0 smooth.
  float roughness = 0.0f;
  // Rough dielectric: renormalise the single-scattering microfacet BSDF so that no energy
  // is lost (material.h). Off only to compare with renderers that lose it (Mitsuba's
  // roughdielectric); JSON "energy_compensation".
  bool energyCompensation = true;
  // Lambert textures: albedo (UsdPreviewSurface diffuseColor) and emission from an rgb
  // output; opacity from one channel.
  TextureDesc albedoTexture, emissionTexture, opacityTexture;
  // Lambert presence (cut-outs): the surface is there with probability `opacity` at a
  // point, or where opacity >= opacityThreshold when the threshold is > 0 (UsdPreviewSurface
  // masking); light passes straight through elsewhere. opacityTexture, when set, gives the
  // opacity. (The front ends read an untextured opacity < 1 without a threshold as glass,
  // a Dielectric, instead.)
  float opacity = 1.0f;
  float opacityThreshold = 0.0f;
  bool hasTextures() const { return albedoTexture.enabled() || emissionTexture.enabled() || opacityTexture.enabled(); }
  bool hasCutouts() const { return type == MaterialType::Lambert && (opacity < 1 || opacityTexture.enabled()); }
};

enum class LightType { Distant, Sphere, Rect, Dome, Disk, Cylinder, Mesh };

// UsdLuxShapingAPI on an area light: its radiance toward an emission direction ω scaled by
// the cone (off the light's axis, its local −Z, by θ: 1 up to θ_c (1 − softness), then
// falling smoothly to 0 at θ_c, 0 beyond) and tinted by focus (lerp(focusTint, 1,
// |n·ω|^focus), n the emitting surface's normal), and scaled by an IES profile (ies.h):
// its candela toward ω in the light's frame, at the vertical angle θ_ies that angleScale s
// maps θ to (UsdLux: θ / s for s > 0, π + (θ − π) / −s for s < 0, θ for 0; 0 where θ_ies
// leaves [0, π]), divided by the profile's mean (IesProfile::meanIntensity) when
// iesNormalize. The fallbacks are UsdLux's.
struct LightShaping {
  bool enabled = false;       // ShapingAPI applied (its inputs authored or given)
  float coneAngle = 90.0f;    // θ_c, degrees
  float coneSoftness = 0.0f;  // clamped to [0, 1]
  float focus = 0.0f;         // below 0: 0
  Vec3 focusTint{0.0f};
  std::string iesFile;        // an IES LM-63 profile (empty: none)
  float iesAngleScale = 0.0f;
  bool iesNormalize = false;
};

struct LightDesc {
  std::string name;
  LightType type = LightType::Distant;
  Transform xf;              // light-to-world
  Vec3 color{1.0f};
  float intensity = 1.0f;
  float exposure = 0.0f;     // radiance = color * intensity * 2^exposure
  bool normalize = false;    // divide by the light's area (or cone solid angle)
  float angle = 0.53f;       // Distant: angular diameter in degrees
  float radius = 0.5f;       // Sphere, Disk (in its local XY plane), Cylinder
  float width = 1.0f, height = 1.0f;  // Rect, in its local XY plane
  float length = 1.0f;       // Cylinder, along its local X axis
  LightShaping shaping;      // Sphere, Rect, Disk, Cylinder
  std::string textureFile;   // Dome: lat-long EXR (empty: constant)
  // Mesh (UsdLuxMeshLightAPI): the emitting triangles in the light's own space (xf places
  // them), each emitting from its front (counter-clockwise seen from there, as a mesh's
  // outside), or from both sides when doubleSided. The mesh is the light's body, as a
  // rect's quad is: it emits, blocks the rays that meet its emitting sides and reflects
  // nothing. No shaping.
  TriangleMesh mesh;
  bool doubleSided = false;
  // A USD front end's mesh light (light:materialSyncMode materialGlowTintsLight, MeshLightAPI's
  // fallback): the bound material's emissive colour multiplies `color`, applied by
  // assembleGranularScene (granular_prims.h), which clears it.
  bool tintByMaterial = false;
  // Light linking (UsdLuxLightAPI's collection:lightLink): empty, the light lights every
  // object; else only the meshes, aggregates and instanced grains whose linkCategories hold
  // this name. At every vertex of a path (a surface's, a grain's, a proxy's, the medium's,
  // DA's) the light then counts only if it lights that vertex's object, sampled or met;
  // what the objects it lights pass on still reaches the others. The camera sees it.
  std::string lightLink;
  // Shadow linking (UsdLuxShadowAPI's collection:shadowLink, inputs:shadow:enable): empty,
  // every object casts shadows from the light; else only the objects whose linkCategories
  // hold this name. shadows false: no object does. An object that casts none is passed by
  // the light's shadow rays from other objects (its surfaces, grains, proxies and media);
  // its shadow on itself stays. Rays sampled by scattering still meet it; the light they
  // would bring past it is counted where they were sampled (ept.h: addDirectPastNonCasters).
  // Area lights' own bodies always block.
  std::string shadowLink;
  bool shadows = true;
};

struct MeshDesc {
  std::string name;
  TriangleMesh mesh;         // object space
  Transform xf;              // object-to-world
  int material = -1;         // index into SceneDesc::materials; -1: default grey Lambert
  bool visible = true;
  int id = -1;               // the front end's id, reported by the primId AOV (Hydra: prim id)
  // The index of the instance this mesh is of a flattened instancer (a PointInstancer's
  // instance index), reported by the instanceId AOV; -1: not instanced. >= -1.
  int instanceId = -1;
  std::vector<std::string> linkCategories;  // the light- and shadow-link names that include it (LightDesc::lightLink, shadowLink)
  // Transform motion blur: the object-to-world transforms at the camera's shutter open and
  // close (CameraDesc); the mesh moves vertex by vertex linearly between them over the
  // shutter (Embree's linear motion blur). Unset, or without an open shutter: still at xf.
  std::optional<std::pair<Transform, Transform>> shutterXf;
};

struct GrainPrototypeDesc {
  std::string name;
  TriangleMesh mesh;         // any placement/scale: normalised into its bounding sphere at build
  int material = -1;         // index into SceneDesc::materials; -1: clear dielectric, IOR 1.5
};

struct AggregateDesc {
  std::string name;
  TriangleMesh boundary;     // closed, object space
  Transform xf;              // object-to-world
  std::vector<GrainPrototypeDesc> prototypes;
  std::vector<float> weights;  // one per prototype, >= 0, not all zero: a grain's probability (by number)
  float grainRadius = 0.01f;   // bounding-sphere radius in world units (of size 1)
  // Polydisperse grains: each prototype's bounding radius relative to grainRadius (empty:
  // all 1; [0.1, 10], the largest at most 10 times the smallest), and the spread of each
  // grain's radius about its prototype's: a factor uniform in [1 − spread, 1 + spread]
  // ([0, 0.5]). Absorption stays per grainRadius, so a larger grain of one material
  // absorbs more across (packing.h, tt.h).
  std::vector<float> sizes;
  float sizeSpread = 0;
  float packingRate = 0.6f;    // f in (0, 0.64]
  uint64_t seed = 1;
  int tileSpheres = 512;       // spheres per periodic tile
  // The memory a distance field of a quarter tile may take (Aggregate::build, by
  // DistanceField::estimateBytes); past it, half a tile. No front end sets it: tests set 0
  // to build the coarser field.
  double fineFieldBytes = 32.0 * 1024 * 1024;
  int id = -1;                 // the front end's id, reported by the primId AOV
  int instanceId = -1;         // as MeshDesc::instanceId
  std::vector<std::string> linkCategories;  // as MeshDesc::linkCategories
  // Transform motion blur, as MeshDesc::shutterXf: the object-to-world transforms at the
  // shutter's open and close, blended linearly between them (aggregate_motion.h). The
  // aggregate is built at xf whatever its motion (no rebuild for it, no other grains).
  std::optional<std::pair<Transform, Transform>> shutterXf;
};

// A unit quaternion (w, x, y, z): the rotation of a grain.
struct Quat {
  float w = 1, x = 0, y = 0, z = 0;
};

inline Vec3 rotate(const Quat& q, const Vec3& v) {
  const Vec3 u(q.x, q.y, q.z);
  const Vec3 t = cross(u, v) * 2.0f;
  return v + t * q.w + cross(u, t);
}

// A PointInstancer's grains as a simulation placed them (instanced_grains.h: the contract).
// The per-grain arrays are shared by copies of the description (shared_array.h: copying a
// scene description costs nothing per grain; writing to a copy copies that array).
struct InstancedGrainsDesc {
  std::string name;                          // the instancer's prim path
  Transform xf;                              // object-to-world
  std::vector<GrainPrototypeDesc> prototypes;
  SharedArray<Vec3> positions;               // object space (USD point3f)
  SharedArray<Quat> orientations;            // unit; empty: identity
  SharedArray<float> scales;                 // uniform, > 0; empty: 1
  SharedArray<int32_t> protoIndices;         // one per grain: the number of grains
  // Motion blur (CameraDesc's shutter); empty or one per grain. Object units per second,
  // and degrees per second about an axis through the instance's position, as USD authors
  // them: at time τ grain i is at positions[i] + τ velocities[i], turned by
  // R(angularVelocities[i], τ |angularVelocities[i]|) after its orientation
  // (UsdGeomPointInstancer::ComputeInstanceTransformsAtTime's convention).
  SharedArray<Vec3> velocities;
  SharedArray<Vec3> angularVelocities;
  int id = -1;                               // the front end's id (primId AOV)
  std::vector<std::string> linkCategories;   // as MeshDesc::linkCategories
  size_t size() const { return protoIndices.size(); }
};

// Which transports the integrator may use (Meng et al. 2015's switching between EPT, VPT and
// DA). Ept is the reference.
enum class Technique { Ept, EptVpt, Hybrid };

// Where proxies (proxy.h, ppt.h) carry a path's low orders after its first grain: never,
// where they are needed (Auto: in aggregates whose medium is measured biased right after
// the first grain, switching.h, and everywhere under a narrow sun, Scene::narrowSun), or
// always (On). Techniques ept+vpt and hybrid; EPT, the reference, never uses them.
enum class ProxyUse { Off, Auto, On };

// The equivalent medium's transport (vpt.h). Tt: Meng et al. 2015's teleportation
// transport — flights of λ_t, each scattering where its flight ends. Exits: flights to the
// next grain met (λ_β, tt.h's kExitFlight), each scattering's light then moved as the grain
// moves light it turns by that angle (tt.h, ExitMoves): light sent back leaves near where it
// came in, light sent on about a diameter further.
enum class MediumModel { Tt, Exits };

struct RenderSettings {
  int width = 640, height = 480;
  int spp = 16;
  uint64_t seed = 0;
  // Events a path may have (interfaces, scatterings; a proxy visit 2). Clear grains' paths
  // are long: in a clear IOR 2.4 ball of 100 grains across, 4096 cut 1.3% of the light.
  int maxDepth = 1 << 16;
  int rrDepth = 8;             // Russian roulette starts after this many bounces
  int threads = 0;             // 0: all cores
  Technique technique = Technique::Hybrid;  // EPT, EPT+VPT or EPT+VPT+DA
  int bundleSize = 16;         // N: paths of a pixel traced in lock-step (Meng et al. 2015: 16)
  // Switch EPT->VPT when σ_k > τ R_max N_k/N: σ_k is the RMS distance of the bundle's N_k
  // live vertices to their centroid, τ R_max a length (τ in units of the largest grain radius).
  float tau = 4.0f;
  // Low orders stay explicit: neither the bundle switch nor the level-of-detail shortcut
  // moves a path into the medium before this many bounces. The medium is memoryless (a
  // Poisson medium); a dense packing is not: light scattered back near the surface leaves
  // through the gaps it came in by (shadow hiding), which the medium misses — up to 6–9%
  // too dark on absorbing and high-IOR grains when paths switched at once, nothing on
  // clear ones, whose energy does not depend on where it leaves (bench/accuracy_matrix.py).
  // -1: automatic, measured per aggregate (switching.h: the proxy visits after which the
  // medium's bias is within tolerance; kProxyOrders bounces per visit without proxies).
  int explicitBounces = -1;
  // Diffusion (technique Hybrid, diffusion.h): DA replaces VPT at a scattering deeper than
  // daDepthFactor × Meng et al. 2015's min(1/σ'_t, 0.5/σ_tr), of a path that has scattered
  // at least daMinOrder times (EPT and VPT events: diffusion models multiply scattered light).
  // The beam DA holds at the paper's depth (factor 1: half spaces and slabs within 1–2% of
  // VPT, tests/core/test_diffusion.cpp); the former point-source DA needed 2. Order 16:
  // lower orders measured up to −0.65% bias on bright sand for 14% more speed
  // (bench/README.md, "Diffusion").
  float daDepthFactor = 1.0f;
  int daMinOrder = 16;
  // DA also in the heterogeneous media of instancers' grains, where the packing is close
  // enough to homogeneous over what the diffusion depends on (heterogeneous_diffusion.h);
  // false: VPT to the end there. Off by default: on the generated heaps it saved no
  // render time at equal error (bench/README.md) and its distance field costs set-up.
  bool daInstanced = false;
  // The most continuations a path splits into at the switch (memory and time per pixel).
  static constexpr float kMaxSplit = 8.0f;
  // Russian roulette and splitting at the switch to the medium: a path goes on as P_a
  // continuations on average, each weighted 1/P_a (hybrid.h): it survives with probability
  // P_a in (0, 1), splits above 1, up to kMaxSplit. Negative: P_a tuned by a pre-render to
  // the least cost of a given variance (hybrid.h: tuneRoulette).
  float roulette = -1.0f;
  // Level of detail: where a path first meets an aggregate and the grain radius is under
  // lod × the ray cone's footprint width there, only that first grain is met — as a proxy
  // where proxies are not off, else explicitly — and the path then enters the medium after
  // its low orders (ept.h). 0: off, today's images exactly; the default shortcuts grains
  // narrower than the footprint.
  float lod = 0.5f;
  // Proxies (ProxyUse): after a path's first grain, its low orders (the explicit bounces
  // above) scatter off the grains' bounding spheres at their true positions by tabulated
  // grain scattering instead of tracing the grains.
  ProxyUse proxies = ProxyUse::Auto;
  // The equivalent medium's transport (MediumModel); Tt is what the benches' tables measure
  // unless they say otherwise.
  MediumModel mediumModel = MediumModel::Tt;
  // Whether camera rays see dome lights (Hydra hosts may hide the background while its
  // light still illuminates the scene).
  bool domeCameraVisible = true;
  // A stage with no light at all (no light, no emissive visible surface) is lit by a
  // uniform white dome of radiance 1, as other path tracers' default world; false: black.
  bool defaultLight = true;
  // Delta suns (distant lights of angle ~0) become the physical sun, a 0.53° disk of the
  // same irradiance, in scenes with smooth dielectric grains (Scene::widenedSuns): light
  // refracted through a grain can never reach a delta light. false keeps them delta (to
  // compare with renderers that lose that light, as bench/validate_mitsuba.py does).
  bool physicalSun = true;
  // Path regularisation of narrow suns (degrees; 0: off). A chain of smooth bounces off or
  // through grains reaches a sun only by hitting its disk, with a chance ~ its solid angle:
  // under the 0.53° sun a few such paths carry the chain's light, as fireflies; a rough
  // grain smaller than a pixel shows its highlight in a few samples likewise. Paths whose
  // last bounce was smooth and that met a grain, and the light samples of rough grains, see
  // a sun narrower than this angle as a disk of the same irradiance, as wide as this angle
  // or as the spread of the chain's direction over the path's footprint (at least the first
  // grain's reflections', 2 w / R; more as the chain bends through more faces, or turns
  // off a rough grain as its mirror would), whichever is less: a grain the pixels resolve keeps
  // its sharp glint (Kaplanyan and Dachsbacher 2013 widen the BSDF
  // instead; a wider light is the same trade). Biased: glints of grains smaller than the
  // footprint are blurred to this size. Proxies see the disk of this angle (their tables'
  // densest cells toward a narrow sun are fireflies too, and a proxy's grain, drawn anew at
  // each visit, holds no glint a pixel could resolve; next-event estimation and the
  // escapes after a proxy alike, so MIS stays whole). Light that next-event estimation
  // reaches elsewhere (the medium, meshes) and what the camera or a smooth mesh shows of
  // the sun stay exact. Delta suns kept delta (physicalSun false) are left alone.
  // 20°: the noise of a 20° sun's glints (bench/README.md, "Rough grains and the 20° default").
  float sunRegularization = 20.0f;
  static constexpr float kMaxSunRegularization = 45.0f;
  float sunRegularizationHalfAngle() const { return 0.5f * sunRegularization * kPi / 180.0f; }  // radians
  // The switch from proxies to the medium measured for this view too (switching.h:
  // measureViewSwitch): each aggregate the camera sees takes the larger of the dome's
  // choice and the view's. The dome's albedo averages over where light leaves; the
  // medium's error hides toward the light at grazing views, as on a beach seen with the
  // sun behind the camera. Costs about a render of the aggregate's pixels at 256 spp of
  // 64 × 48 (bench/README.md, "The switch for a view") per new view, cached on disk.
  bool switchForView = false;
  // Crop: only the pixels [cropX0, cropX1) × [cropY0, cropY1) of the width × height image
  // are rendered (a tile of a farm job, UsdRenderSettings dataWindowNDC); all 0 (the
  // default): every pixel. A pixel's samples depend on (seed, pixel, sample index) only and
  // the roulette pre-render always covers the whole image, so the crops of a tiling,
  // merged, equal the full render bit for bit (tests/core/test_render_crop.cpp).
  int cropX0 = 0, cropX1 = 0, cropY0 = 0, cropY1 = 0;
  // The film keeps Cryptomatte tables (film.h) and images get the CryptoObject and
  // CryptoMaterial layers; off: no memory for them.
  bool cryptomatte = false;
};

// A pixel window [x0, x1) × [y0, y1) of an image.
struct PixelWindow {
  int x0 = 0, x1 = 0, y0 = 0, y1 = 0;
  int width() const { return x1 - x0; }
  int height() const { return y1 - y0; }
  bool operator==(const PixelWindow& o) const { return x0 == o.x0 && x1 == o.x1 && y0 == o.y0 && y1 == o.y1; }
  bool operator!=(const PixelWindow& o) const { return !(*this == o); }
};

// The pixels a render covers: the crop, or the whole image when the crop is all 0.
PixelWindow renderWindow(const RenderSettings& s);

// UsdRenderSettings' dataWindowNDC (xmin, ymin, xmax, ymax; (0, 0) the image's lower left,
// (1, 1) its upper right) as the pixels of a width × height image it covers, rows from the
// top: every pixel covered even in part (an edge within 1e-4 pixel of a pixel edge counts as
// on it, so that float values such as 0.3 pick up no sliver), clipped to the image (no
// overscan); an empty window (width() <= 0) when nothing of the image is left.
PixelWindow pixelWindowFromNdc(double xmin, double ymin, double xmax, double ymax, int width, int height);

struct SceneDesc {
  CameraDesc camera;
  std::vector<MaterialDesc> materials;
  std::vector<MeshDesc> meshes;
  std::vector<LightDesc> lights;
  std::vector<AggregateDesc> aggregates;
  // Explicit grains from simulations (instanced_grains.h), rendered grain by grain.
  std::vector<InstancedGrainsDesc> instancedGrains;
  RenderSettings settings;
};

// Render space (camera-relative rendering's aim, with an origin that does not move with
// the camera): everything is built and traced in world space translated by −origin, the
// translation applied in double to each transform, so that what needs float precision —
// the grains — sits near zero wherever the stage puts it. The origin is the centre of the
// aggregates' world bounds (else of the visible meshes', else the camera's position),
// rounded to a grid of whole units as coarse as their extent (a power of two). It does not
// depend on the camera, so a camera move keeps a built scene; a stage moved by a multiple
// of the grid keeps its render space, to the double rounding of its transforms; a stage
// near the world origin renders in world space itself.
Vec3d renderOrigin(const SceneDesc& desc);
// The description with every transform (camera, meshes, lights, aggregates) premultiplied
// by translate(−origin).
SceneDesc toRenderSpace(const SceneDesc& desc, const Vec3d& origin);
CameraDesc toRenderSpace(const CameraDesc& camera, const Vec3d& origin);

// Float precision at the grains: an aggregate whose grains lie so far from the render
// origin that a position there rounds by more than kGrainPrecision of a grain radius
// (float spacing of the render-space coordinate plus double spacing of the world one)
// would lose or mangle its grains; InputError on its grainRadius naming the distance.
constexpr double kGrainPrecision = 1.0 / 64;
void checkGrainPrecision(const AggregateDesc& renderSpaceAggregate, const Vec3d& origin);

// UsdUVTexture's tokens, for every front end: wrapS/T ("useMetadata", "black", "clamp",
// "repeat", "mirror"), sourceColorSpace ("auto", "raw", "sRGB") and its outputs as a
// TextureDesc::channel ("rgb" -1, "r" 0, "g" 1, "b" 2, "a" 3). Anything else is an
// InputError on obj.attr listing what is allowed.
TextureWrap textureWrapFromName(const std::string& name, const std::string& obj, const std::string& attr);
TextureColorSpace textureColorSpaceFromName(const std::string& name, const std::string& obj, const std::string& attr);
int textureChannelFromName(const std::string& name, const std::string& obj, const std::string& attr);

// "ept", "ept+vpt", "hybrid"; anything else is an InputError on obj.technique.
Technique techniqueFromName(const std::string& name, const std::string& obj);
const char* techniqueName(Technique t);
ProxyUse proxyUseFromName(const std::string& name, const std::string& obj);
const char* proxyUseName(ProxyUse p);
// "tt", "exits"; anything else is an InputError on obj.medium_model.
MediumModel mediumModelFromName(const std::string& name, const std::string& obj);
const char* mediumModelName(MediumModel m);

// What a front end that keeps a built scene (render --frames, the farm's workers, the
// Hydra delegate) must redo for a new description of the same stage, as the most work it
// needs: nothing; a new view (Scene::setView); or Scene::build given the previous scene,
// which then reuses every aggregate not listed in SceneChanges::aggregates — for new lights,
// for some aggregates, or for everything else (surfaces, materials, media, render space).
enum class SceneChange { Unchanged, View, Lights, Aggregates, Everything };

struct SceneChanges {
  bool camera = false;        // the CameraDesc
  bool settings = false;      // render settings that Scene::setView applies
  bool lights = false;        // the lights, or the settings that decide them (defaultLight, physicalSun)
  // Indices into the new description's aggregates that no aggregate of the old one can lend
  // its grains to: new ones, and those whose inputs (their AggregateDesc but the id and the
  // motion, their prototypes' materials) changed. Scene::build voxelises these.
  std::vector<int> aggregates;
  bool aggregateList = false;  // aggregates removed, reordered or given other ids (none made anew for it)
  // An aggregate's motion over the shutter (its shutterXf, or the shutter while it has one):
  // a build that lends it unchanged and moves it anew.
  bool aggregateMotion = false;
  bool meshes = false;         // any MeshDesc, or their count
  bool materials = false;      // a material that is not a grain's alone (a surface's, an unused one), or their count
  bool media = false;          // the technique to or from ept, or the medium model: every aggregate's medium made anew or dropped
  bool renderSpace = false;    // renderOrigin() moved: surfaces and lights in render space (aggregates compare there)
  bool instancedGrains = false;  // an instancer's grains, prototypes or id, or their count (Scene::build lends the rest)
  SceneChange level() const;
};

// Field-by-field equality (floats by value), as compareScenes compares them and Scene::build
// lends a built aggregate on the same terms.
bool sameTransform(const Transform& a, const Transform& b);
bool sameMesh(const TriangleMesh& a, const TriangleMesh& b);
bool sameMaterial(const MaterialDesc& a, const MaterialDesc& b);
// Every field but the id (prototype materials by index; Scene::build compares their values).
bool sameInstancedGrains(const InstancedGrainsDesc& a, const InstancedGrainsDesc& b);

// Compares every field of two descriptions (floats by value: a NaN always differs).
SceneChanges compareScenes(const SceneDesc& before, const SceneDesc& after);
// Whether new settings need Scene::build rather than Scene::setView: the technique to or
// from ept (media or none), the medium model, defaultLight or physicalSun (the lights built).
bool settingsNeedBuild(const RenderSettings& before, const RenderSettings& after);
// For logs: "unchanged", "new camera", "new camera and settings", "lights changed",
// "lights and 2 aggregates changed", "everything (meshes and materials) changed".
std::string describeChanges(const SceneChanges& changes);

// Checks every value a user can get wrong; throws InputError naming object and attribute.
void validateSceneDesc(const SceneDesc& desc);

// No motion blur (JSON "motion_blur": false, --no-motion-blur, UsdRender's
// disableMotionBlur): the frame's instant, the camera's shutter closed at 0 and every mesh
// and aggregate still at its transform (MeshDesc::shutterXf, AggregateDesc::shutterXf
// dropped); moving grains then stand still too.
void stillFrame(SceneDesc& desc);

// Parts of validateSceneDesc, for front ends that check what they add as they go: one
// material; an aggregate's transform, grain radius, packing rate, tile spheres, prototype
// count and weights (not its meshes: validateClosed, nor its material indices); one light.
void validateMaterialDesc(const MaterialDesc& m, const std::string& object);
// geometry false: all but a mesh light's triangles and what depends on them (the area a
// normalised light divides by), for a USD mesh light before its front end's mesh is given.
void validateLightDesc(const LightDesc& l, const std::string& object, bool geometry = true);
// One camera on its own (not its field of view, which depends on the image's aspect).
void validateCameraDesc(const CameraDesc& c, const std::string& object);
void validateAggregateParameters(const AggregateDesc& a, const std::string& object);
// An aggregate's shutterXf (set): each transform as its xf, and their linear blend invertible
// over the shutter, its determinant at least kMinBlendDeterminantRatio of the ends' least.
void validateAggregateMotion(const AggregateDesc& a, const std::string& object);
// The least over s in [0, 1] of det((1 − s) A + s B) (linear parts) over the least of
// det A and det B, of their sign; <= 0: the blend flips or is singular somewhere.
double minBlendDeterminantRatio(const Transform& a, const Transform& b);
constexpr double kMinBlendDeterminantRatio = 0.25;  // cos²(60°): a turn of 120° over the shutter

}  // namespace granular
