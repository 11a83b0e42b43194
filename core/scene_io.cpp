// scene_io.cpp — JSON scene reader (format documented in scene_io.h).
//
// Every value goes through a checked converter that names the object and key, so a
// wrong type becomes an InputError rather than a nlohmann exception; each JSON object
// declares its allowed keys up front so a typo is reported before anything it causes.
#include "scene_io.h"

#include <algorithm>
#include <cerrno>
#include <climits>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <nlohmann/json.hpp>

#include "error.h"
#include "shapes.h"

namespace granular {

namespace {

using json = nlohmann::json;
namespace fs = std::filesystem;

std::string preview(const json& v) {
  std::string s = v.dump(-1, ' ', /*ensure_ascii=*/true);  // cut below: never inside a character
  return s.size() > 40 ? s.substr(0, 37) + "..." : s;
}
std::string describe(const json& v) { return str(v.type_name(), " ", preview(v)); }

std::string join(const std::vector<std::string>& items) {
  std::string r;
  for (const std::string& s : items) r += (r.empty() ? "" : ", ") + s;
  return r;
}

// The message of an InputError without its "object.attribute: " prefix.
std::string bareMessage(const InputError& e) {
  std::string w = e.what();
  size_t n = e.object().size() + (e.attribute().empty() ? 0 : e.attribute().size() + 1) + 2;
  return w.size() >= n ? w.substr(n) : w;
}

// Desc fields are camelCase (USD names), JSON keys their snake_case spelling.
std::string camelToSnake(const std::string& s) {
  std::string r;
  for (char c : s) {
    if (c >= 'A' && c <= 'Z') {
      r += '_';
      r += char(c - 'A' + 'a');
    } else {
      r += c;
    }
  }
  return r;
}

// Runs f, re-labelling an InputError from a layer that does not know the JSON names.
template <typename F>
auto relabel(const std::string& object, F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const InputError& e) {
    throw InputError(object, camelToSnake(e.attribute()), bareMessage(e));
  }
}

// ---- checked scalar converters -------------------------------------------------

double toNumber(const json& v, const std::string& obj, const std::string& key) {
  if (!v.is_number()) throw InputError(obj, key, "expected a number, got " + describe(v));
  return v.get<double>();
}

float toFloat(const json& v, const std::string& obj, const std::string& key) {
  double d = toNumber(v, obj, key);
  if (!std::isfinite(float(d))) throw InputError(obj, key, str(preview(v), " does not fit in a float"));
  return float(d);
}

long long toInteger(const json& v, const std::string& obj, const std::string& key) {
  if (v.is_number_unsigned()) {
    uint64_t u = v.get<uint64_t>();
    if (u > uint64_t(LLONG_MAX)) throw InputError(obj, key, str(u, " is out of range"));
    return (long long)u;
  }
  if (v.is_number_integer()) return v.get<long long>();
  if (v.is_number_float()) {
    double d = v.get<double>();
    if (d == std::floor(d) && std::fabs(d) < 9.0e18) return (long long)d;
  }
  throw InputError(obj, key, "expected an integer, got " + describe(v));
}

int toInt(const json& v, const std::string& obj, const std::string& key) {
  long long x = toInteger(v, obj, key);
  if (x < INT_MIN || x > INT_MAX) throw InputError(obj, key, str(x, " is out of range"));
  return int(x);
}

uint64_t toU64(const json& v, const std::string& obj, const std::string& key) {
  if (v.is_number_unsigned()) return v.get<uint64_t>();
  long long x = toInteger(v, obj, key);
  if (x < 0) throw InputError(obj, key, str(x, " must be >= 0"));
  return uint64_t(x);
}

bool toBool(const json& v, const std::string& obj, const std::string& key) {
  if (!v.is_boolean()) throw InputError(obj, key, "expected true or false, got " + describe(v));
  return v.get<bool>();
}

std::string toString(const json& v, const std::string& obj, const std::string& key) {
  if (!v.is_string()) throw InputError(obj, key, "expected a string, got " + describe(v));
  return v.get<std::string>();
}

const json& toArray(const json& v, const std::string& obj, const std::string& key) {
  if (!v.is_array()) throw InputError(obj, key, "expected an array, got " + describe(v));
  return v;
}

// [x, y, z]; a single number s means (s, s, s) where allowScalar (colours, scale).
Vec3 toVec3(const json& v, const std::string& obj, const std::string& key, bool allowScalar = false) {
  if (allowScalar && v.is_number()) return Vec3(toFloat(v, obj, key));
  if (!v.is_array() || v.size() != 3)
    throw InputError(obj, key, str("expected an array of 3 numbers", allowScalar ? " or a number" : "", ", got ", describe(v)));
  return {toFloat(v[0], obj, key), toFloat(v[1], obj, key), toFloat(v[2], obj, key)};
}

std::vector<float> toFloats(const json& v, const std::string& obj, const std::string& key) {
  std::vector<float> r;
  for (const json& e : toArray(v, obj, key)) r.push_back(toFloat(e, obj, key));
  return r;
}

// ---- objects with a declared set of keys ----------------------------------------

class Obj {
 public:
  // `v` is the value of `key` in `parent` (for messages); `label` names it as an object.
  Obj(const json& v, const std::string& parent, const std::string& key, std::string label,
      std::vector<std::string> allowed)
      : j_(v), label_(std::move(label)) {
    if (!v.is_object()) throw InputError(parent, key, "expected an object, got " + describe(v));
    std::sort(allowed.begin(), allowed.end());
    for (auto it = v.begin(); it != v.end(); ++it)
      if (!std::binary_search(allowed.begin(), allowed.end(), it.key()))
        throw InputError(label_, it.key(), "unknown key (allowed: " + join(allowed) + ")");
  }
  const std::string& label() const { return label_; }
  const json* find(const std::string& k) const {
    auto it = j_.find(k);
    return it == j_.end() ? nullptr : &*it;
  }
  bool has(const std::string& k) const { return find(k) != nullptr; }
  const json& required(const std::string& k) const {
    const json* v = find(k);
    if (!v) throw InputError(label_, k, "is required");
    return *v;
  }
  float num(const std::string& k, float def) const { return has(k) ? toFloat(*find(k), label_, k) : def; }
  int integer(const std::string& k, int def) const { return has(k) ? toInt(*find(k), label_, k) : def; }
  uint64_t u64(const std::string& k, uint64_t def) const { return has(k) ? toU64(*find(k), label_, k) : def; }
  bool flag(const std::string& k, bool def) const { return has(k) ? toBool(*find(k), label_, k) : def; }
  std::string string(const std::string& k, const std::string& def) const {
    return has(k) ? toString(*find(k), label_, k) : def;
  }
  Vec3 vec3(const std::string& k, Vec3 def, bool allowScalar = false) const {
    return has(k) ? toVec3(*find(k), label_, k, allowScalar) : def;
  }

 private:
  const json& j_;
  std::string label_;
};

// ---- transforms --------------------------------------------------------------------

Transform matrixFrom(const json& v, const std::string& obj, const std::string& key) {
  if (!v.is_array() || v.size() != 16)
    throw InputError(obj, key, "expected an array of 16 numbers (row-major), got " + describe(v));
  Transform t;
  for (int i = 0; i < 16; ++i) t.m[i / 4][i % 4] = toNumber(v[i], obj, key);
  // A USD-style (row-vector) matrix has its translation in the bottom row; catch it.
  if (t.m[3][0] != 0 || t.m[3][1] != 0 || t.m[3][2] != 0 || t.m[3][3] != 1)
    throw InputError(obj, key,
                     str("bottom row (", t.m[3][0], ", ", t.m[3][1], ", ", t.m[3][2], ", ", t.m[3][3],
                         ") must be (0, 0, 0, 1): the matrix is row-major, acts on column vectors and keeps its "
                         "translation in the last column"));
  return t;
}

Transform rotation(double deg, double ax, double ay, double az) {
  double l = std::sqrt(ax * ax + ay * ay + az * az);
  ax /= l, ay /= l, az /= l;
  double a = deg * kPiD / 180.0, c = std::cos(a), s = std::sin(a), t = 1 - c;
  Transform r;
  r.m[0][0] = t * ax * ax + c;      r.m[0][1] = t * ax * ay - s * az; r.m[0][2] = t * ax * az + s * ay;
  r.m[1][0] = t * ax * ay + s * az; r.m[1][1] = t * ay * ay + c;      r.m[1][2] = t * ay * az - s * ax;
  r.m[2][0] = t * ax * az - s * ay; r.m[2][1] = t * ay * az + s * ax; r.m[2][2] = t * az * az + c;
  return r;
}

Transform parseTransform(const json& v, const std::string& parent, const std::string& key) {
  if (v.is_array()) return matrixFrom(v, parent, key);
  Obj o(v, parent, key, parent + "." + key, {"matrix", "translate", "rotate", "scale"});
  if (o.has("matrix")) {
    if (o.has("translate") || o.has("rotate") || o.has("scale"))
      throw InputError(o.label(), "matrix", "cannot be combined with translate, rotate or scale");
    return matrixFrom(*o.find("matrix"), o.label(), "matrix");
  }
  Transform t = Transform::translate(o.vec3("translate", Vec3(0.0f)));
  Transform r;
  if (const json* rv = o.find("rotate")) {
    if (!rv->is_array() || rv->size() != 4)
      throw InputError(o.label(), "rotate", "expected [angle_degrees, axis_x, axis_y, axis_z], got " + describe(*rv));
    double ang = toFloat((*rv)[0], o.label(), "rotate"), ax = toFloat((*rv)[1], o.label(), "rotate"),
           ay = toFloat((*rv)[2], o.label(), "rotate"), az = toFloat((*rv)[3], o.label(), "rotate");
    if (ax == 0 && ay == 0 && az == 0) throw InputError(o.label(), "rotate", "has a zero axis");
    r = rotation(ang, ax, ay, az);
  }
  Transform s = Transform::scale(o.vec3("scale", Vec3(1.0f), true));
  return t * r * s;
}

// ---- shapes ------------------------------------------------------------------------

struct Context {
  fs::path base;  // folder that relative paths are resolved against
};

std::string resolvePath(const Context& ctx, const std::string& p) {
  fs::path path(p);
  return (path.is_absolute() || ctx.base.empty()) ? path.string() : (ctx.base / path).string();
}

// A file the scene names (a texture, an IES profile): resolved, and refused naming
// label.key when it does not exist.
std::string existingFile(const Context& ctx, const std::string& name, const std::string& label, const char* key) {
  const std::string file = resolvePath(ctx, name);
  std::error_code ec;
  if (!fs::is_regular_file(file, ec)) throw InputError(label, key, str("\"", file, "\" does not exist"));
  return file;
}

struct Vec2f {
  float u, v;
};

std::vector<Vec2f> parseUvs(const json& v, const std::string& obj, const std::string& key) {
  std::vector<Vec2f> out;
  for (const json& e : toArray(v, obj, key)) {
    if (!e.is_array() || e.size() != 2) throw InputError(obj, key, "expected [u, v] pairs, got " + describe(e));
    out.push_back({toFloat(e[0], obj, key), toFloat(e[1], obj, key)});
  }
  return out;
}

std::vector<Vec3> parsePoints(const json& v, const std::string& obj, const std::string& key) {
  const json& a = toArray(v, obj, key);
  std::vector<Vec3> pts;
  if (!a.empty() && a[0].is_number()) {  // flat [x, y, z, x, y, z, ...]
    if (a.size() % 3 != 0) throw InputError(obj, key, str("has ", a.size(), " numbers, not a multiple of 3"));
    for (size_t i = 0; i < a.size(); i += 3)
      pts.push_back({toFloat(a[i], obj, key), toFloat(a[i + 1], obj, key), toFloat(a[i + 2], obj, key)});
  } else {
    for (const json& p : a) pts.push_back(toVec3(p, obj, key));
  }
  return pts;
}

std::vector<int> parseInts(const json& v, const std::string& obj, const std::string& key) {
  std::vector<int> r;
  for (const json& e : toArray(v, obj, key)) r.push_back(toInt(e, obj, key));
  return r;
}

TriangleMesh scaled(TriangleMesh m, float s) {
  for (Vec3& p : m.points) p *= s;
  return m;
}

// `v` is the value of `key` in `parent`, e.g. parent "castle", key "boundary".
TriangleMesh parseShape(const json& v, const std::string& parent, const std::string& key, const Context& ctx) {
  static const std::vector<std::string> kinds = {"box", "ellipsoid", "icosphere", "lathe", "mesh", "obj", "rock", "uvsphere"};
  const std::string label = parent + "." + key;
  if (!v.is_object() || v.size() != 1)
    throw InputError(parent, key, "expected an object with exactly one of " + join(kinds) + ", got " + describe(v));
  const std::string kind = v.begin().key();
  const json& p = v.begin().value();
  const std::string sub = label + "." + kind;
  if (kind == "obj") return loadObj(resolvePath(ctx, toString(p, label, "obj")), label);
  if (kind == "box") {
    Obj o(p, label, kind, sub, {"lo", "hi"});
    Vec3 lo = o.vec3("lo", Vec3(-1.0f)), hi = o.vec3("hi", Vec3(1.0f));
    return relabel(sub, [&] { return makeBox(lo, hi); });
  }
  if (kind == "icosphere" || kind == "uvsphere") {
    bool ico = kind == "icosphere";
    Obj o(p, label, kind, sub, ico ? std::vector<std::string>{"subdivisions", "radius"}
                                   : std::vector<std::string>{"segments", "rings", "radius"});
    float radius = o.num("radius", 1.0f);
    if (!(radius > 0)) throw InputError(sub, "radius", str(radius, " must be > 0"));
    if (ico) {
      int n = o.integer("subdivisions", 2);
      return scaled(relabel(sub, [&] { return makeIcosphere(n); }), radius);
    }
    int segments = o.integer("segments", 32), rings = o.integer("rings", 16);
    return scaled(relabel(sub, [&] { return makeUVSphere(segments, rings); }), radius);
  }
  if (kind == "lathe") {
    Obj o(p, label, kind, sub, {"profile", "segments"});
    std::vector<std::pair<float, float>> profile;
    for (const json& e : toArray(o.required("profile"), sub, "profile")) {
      if (!e.is_array() || e.size() != 2)
        throw InputError(sub, "profile", "expected [radius, height] pairs, got " + describe(e));
      profile.push_back({toFloat(e[0], sub, "profile"), toFloat(e[1], sub, "profile")});
    }
    int segments = o.integer("segments", 64);
    return relabel(sub, [&] { return makeLathe(profile, segments); });
  }
  if (kind == "rock") {
    Obj o(p, label, kind, sub, {"subdivisions", "roughness", "seed"});
    int n = o.integer("subdivisions", 3);
    float rough = o.num("roughness", 0.2f);
    uint64_t seed = o.u64("seed", 0);
    return relabel(sub, [&] { return makeRock(n, rough, seed); });
  }
  if (kind == "ellipsoid") {
    Obj o(p, label, kind, sub, {"radii", "subdivisions"});
    Vec3 radii = toVec3(o.required("radii"), sub, "radii");
    int n = o.integer("subdivisions", 3);
    return relabel(sub, [&] { return makeEllipsoid(radii, n); });
  }
  if (kind == "mesh") {
    Obj o(p, label, kind, sub, {"points", "face_vertex_indices", "face_vertex_counts", "st", "st_interpolation"});
    std::vector<Vec3> pts = parsePoints(o.required("points"), sub, "points");
    std::vector<int> idx = parseInts(o.required("face_vertex_indices"), sub, "face_vertex_indices");
    std::vector<int> counts;
    if (o.has("face_vertex_counts")) {
      counts = parseInts(*o.find("face_vertex_counts"), sub, "face_vertex_counts");
    } else {
      if (idx.size() % 3 != 0)
        throw InputError(sub, "face_vertex_indices",
                         str("has ", idx.size(), " entries, not a multiple of 3 (give face_vertex_counts for polygons)"));
      counts.assign(idx.size() / 3, 3);
    }
    TriangleMesh mesh = relabel(sub, [&] { return triangulate(pts, counts, idx, sub); });
    if (const json* st = o.find("st")) {
      // Texture coordinates, per point ("vertex", the default) or per face vertex.
      std::vector<Vec2f> uv = parseUvs(*st, sub, "st");
      std::string interp = o.string("st_interpolation", "vertex");
      if (interp != "vertex" && interp != "faceVarying")
        throw InputError(sub, "st_interpolation", str("\"", interp, "\" is not vertex or faceVarying"));
      const size_t expected = interp == "vertex" ? pts.size() : idx.size();
      if (uv.size() != expected)
        throw InputError(sub, "st", str(uv.size(), " values for ", expected, interp == "vertex" ? " points" : " face vertices"));
      for (uint32_t c : triangulatedCorners(counts)) {
        const Vec2f& t = uv[interp == "vertex" ? size_t(idx[c]) : size_t(c)];
        mesh.uvs.push_back(t.u);
        mesh.uvs.push_back(t.v);
      }
    }
    return mesh;
  }
  throw InputError(parent, key, str("unknown shape \"", kind, "\" (expected one of ", join(kinds), ")"));
}

// ---- scene sections ----------------------------------------------------------------

using MaterialIndex = std::map<std::string, int>;

int lookupMaterial(const Obj& o, const MaterialIndex& mats, int def) {
  if (!o.has("material")) return def;
  std::string name = o.string("material", "");
  auto it = mats.find(name);
  if (it != mats.end()) return it->second;
  std::vector<std::string> names;
  for (auto& kv : mats) names.push_back("\"" + kv.first + "\"");
  throw InputError(o.label(), "material",
                   str("unknown material \"", name, "\"",
                       names.empty() ? std::string(" (no materials are defined)") : " (defined: " + join(names) + ")"));
}

// An item's label: its "name" if it has one, else list[i].
std::string itemLabel(const json& item, const std::string& list, size_t i) {
  if (item.is_object()) {
    auto it = item.find("name");
    if (it != item.end()) return toString(*it, str(list, "[", i, "]"), "name");
  }
  return str(list, "[", i, "]");
}

void checkUnique(std::set<std::string>& seen, const std::string& name, const std::string& list, size_t i) {
  if (!seen.insert(name).second)
    throw InputError(str(list, "[", i, "]"), "name", str("\"", name, "\" is used by another entry of ", list));
}

void parseRender(const Obj& o, RenderSettings& s) {
  s.width = o.integer("width", s.width);
  s.height = o.integer("height", s.height);
  s.spp = o.integer("spp", s.spp);
  s.seed = o.u64("seed", s.seed);
  s.maxDepth = o.integer("max_depth", s.maxDepth);
  s.rrDepth = o.integer("rr_depth", s.rrDepth);
  s.threads = o.integer("threads", s.threads);
  s.bundleSize = o.integer("bundle_size", s.bundleSize);
  s.tau = o.num("tau", s.tau);
  s.explicitBounces = o.integer("explicit_bounces", s.explicitBounces);
  s.daDepthFactor = o.num("da_depth_factor", s.daDepthFactor);
  s.daMinOrder = o.integer("da_min_order", s.daMinOrder);
  s.daInstanced = o.flag("da_instanced", s.daInstanced);
  s.roulette = o.num("roulette", s.roulette);
  s.lod = o.num("lod", s.lod);
  s.defaultLight = o.flag("default_light", s.defaultLight);
  s.physicalSun = o.flag("physical_sun", s.physicalSun);
  s.sunRegularization = o.num("sun_regularization", s.sunRegularization);
  s.switchForView = o.flag("switch_for_view", s.switchForView);
  if (o.has("proxies")) s.proxies = proxyUseFromName(o.string("proxies", ""), o.label());
  if (o.has("medium_model")) s.mediumModel = mediumModelFromName(o.string("medium_model", ""), o.label());
  if (o.has("technique")) s.technique = techniqueFromName(o.string("technique", ""), o.label());
  if (const json* c = o.find("crop")) {  // [x0, x1, y0, y1], pixels
    const json& a = toArray(*c, o.label(), "crop");
    if (a.size() != 4) throw InputError(o.label(), "crop", "expected [x0, x1, y0, y1], got " + describe(a));
    s.cropX0 = toInt(a[0], o.label(), "crop");
    s.cropX1 = toInt(a[1], o.label(), "crop");
    s.cropY0 = toInt(a[2], o.label(), "crop");
    s.cropY1 = toInt(a[3], o.label(), "crop");
  }
}

void parseCamera(const Obj& o, CameraDesc& c) {
  if (o.has("look_at") && o.has("transform"))
    throw InputError(o.label(), "look_at", "give either look_at or transform, not both");
  if (const json* la = o.find("look_at")) {
    Obj l(*la, o.label(), "look_at", o.label() + ".look_at", {"eye", "target", "up"});
    Vec3 eye = toVec3(l.required("eye"), l.label(), "eye");
    Vec3 target = toVec3(l.required("target"), l.label(), "target");
    Vec3 up = l.vec3("up", Vec3(0, 1, 0));
    if (eye == target) throw InputError(l.label(), "target", "equals eye");
    if (length(cross(up, normalize(target - eye))) < 1e-6f * length(up) || isBlack(up))
      throw InputError(l.label(), "up", "is zero or parallel to the view direction");
    c.cameraToWorld = Transform::lookAt(eye, target, up);
  } else if (const json* t = o.find("transform")) {
    c.cameraToWorld = parseTransform(*t, o.label(), "transform");
  }
  c.focalLength = o.num("focal_length", c.focalLength);
  c.horizontalAperture = o.num("horizontal_aperture", c.horizontalAperture);
  c.verticalAperture = o.num("vertical_aperture", c.verticalAperture);
  c.horizontalApertureOffset = o.num("horizontal_aperture_offset", c.horizontalApertureOffset);
  c.verticalApertureOffset = o.num("vertical_aperture_offset", c.verticalApertureOffset);
  // Depth of field as UsdGeomCamera gives it: f_stop (0: pinhole) and focus_distance.
  c.lensRadius = checkedLensRadius(c.focalLength, o.num("f_stop", 0.0f), o.label(), "f_stop");
  c.focusDistance = o.num("focus_distance", c.focusDistance);  // checked with the lens (validateSceneDesc)
  // Motion blur: the shutter in seconds about the frame (CameraDesc; USD's shutter:open and
  // shutter:close divided by timeCodesPerSecond). The range is checked by validateSceneDesc.
  c.shutterOpen = o.num("shutter_open", c.shutterOpen);
  c.shutterClose = o.num("shutter_close", c.shutterClose);
  if (c.shutterClose < c.shutterOpen)
    throw InputError(o.label(), "shutter_close", str(c.shutterClose, " is before shutter_open ", c.shutterOpen));
  if (const json* cr = o.find("clipping_range")) {
    if (!cr->is_array() || cr->size() != 2)
      throw InputError(o.label(), "clipping_range", "expected [near, far], got " + describe(*cr));
    c.clipNear = toFloat((*cr)[0], o.label(), "clipping_range");
    c.clipFar = toFloat((*cr)[1], o.label(), "clipping_range");
  }
}

// A UsdUVTexture as JSON: {"file", "wrap_s", "wrap_t", "scale", "bias", "color_space",
// "channel"}, names and meanings as in USD (texture.h).
TextureDesc parseTexture(const json& v, const std::string& material, const std::string& key, const Context& ctx,
                         bool colour) {
  const std::string label = material + "." + key;
  Obj o(v, material, key, label, {"file", "wrap_s", "wrap_t", "scale", "bias", "color_space", "channel"});
  TextureDesc t;
  t.source = label;
  t.file = existingFile(ctx, toString(o.required("file"), label, "file"), label, "file");
  t.wrapS = textureWrapFromName(o.string("wrap_s", "useMetadata"), label, "wrap_s");
  t.wrapT = textureWrapFromName(o.string("wrap_t", "useMetadata"), label, "wrap_t");
  for (const char* k : {"scale", "bias"}) {
    if (const json* a = o.find(k)) {
      const json& arr = toArray(*a, label, k);
      if (arr.size() != 4) throw InputError(label, k, "expected 4 numbers (r, g, b, a), got " + describe(*a));
      for (int c = 0; c < 4; ++c) (std::string(k) == "scale" ? t.scale : t.bias)[c] = toFloat(arr[c], label, k);
    }
  }
  t.colorSpace = textureColorSpaceFromName(o.string("color_space", "auto"), label, "color_space");
  t.channel = textureChannelFromName(o.string("channel", colour ? "rgb" : "r"), label, "channel");
  if (!colour && t.channel < 0) throw InputError(label, "channel", "a float input takes r, g, b or a, not rgb");
  return t;
}

void parseMaterials(const json& v, SceneDesc& desc, MaterialIndex& index, const Context& ctx) {
  if (!v.is_object())
    throw InputError("scene", "materials", "expected an object mapping names to materials, got " + describe(v));
  for (auto it = v.begin(); it != v.end(); ++it) {
    const std::string& name = it.key();
    if (name.empty()) throw InputError("materials", "", "a material has an empty name");
    const json& m = it.value();
    std::string type = "lambert";
    if (m.is_object() && m.contains("type")) type = toString(m.at("type"), name, "type");
    MaterialDesc md;
    md.name = name;
    if (type == "lambert") {
      Obj o(m, "materials", name, name,
            {"type", "albedo", "emission", "albedo_texture", "emission_texture", "opacity", "opacity_texture",
             "opacity_threshold"});
      md.type = MaterialType::Lambert;
      md.albedo = o.vec3("albedo", md.albedo, true);
      md.emission = o.vec3("emission", md.emission, true);
      md.opacity = o.num("opacity", md.opacity);
      md.opacityThreshold = o.num("opacity_threshold", md.opacityThreshold);
      if (const json* t = o.find("albedo_texture")) md.albedoTexture = parseTexture(*t, name, "albedo_texture", ctx, true);
      if (const json* t = o.find("emission_texture")) md.emissionTexture = parseTexture(*t, name, "emission_texture", ctx, true);
      if (const json* t = o.find("opacity_texture")) md.opacityTexture = parseTexture(*t, name, "opacity_texture", ctx, false);
    } else if (type == "dielectric") {
      Obj o(m, "materials", name, name, {"type", "ior", "absorption", "roughness", "energy_compensation"});
      md.type = MaterialType::Dielectric;
      md.ior = o.num("ior", md.ior);
      md.absorption = o.vec3("absorption", md.absorption, true);
      md.roughness = o.num("roughness", md.roughness);
      md.energyCompensation = o.flag("energy_compensation", md.energyCompensation);
    } else {
      throw InputError(name, "type", str("unknown material type \"", type, "\" (expected lambert or dielectric)"));
    }
    index[name] = int(desc.materials.size());
    desc.materials.push_back(md);
  }
}

// An aggregate's or an instancer's grain prototypes: [{"name", "shape"*, "material"}], named
// like USD child prims ("castle/rock"), else "castle.prototypes[j]".
std::vector<GrainPrototypeDesc> parsePrototypes(const json& v, const std::string& label, const MaterialIndex& mats,
                                                const Context& ctx) {
  std::vector<GrainPrototypeDesc> out;
  const json& protos = toArray(v, label, "prototypes");
  std::set<std::string> protoNames;
  for (size_t k = 0; k < protos.size(); ++k) {
    std::string indexed = str(label, ".prototypes[", k, "]");
    GrainPrototypeDesc p;
    p.name = indexed;
    if (protos[k].is_object() && protos[k].contains("name")) {
      std::string n = toString(protos[k].at("name"), indexed, "name");
      if (!protoNames.insert(n).second)
        throw InputError(indexed, "name", str("\"", n, "\" is used by another prototype of ", label));
      p.name = label + "/" + n;
    }
    Obj po(protos[k], label, str("prototypes[", k, "]"), p.name, {"name", "shape", "material"});
    p.mesh = parseShape(po.required("shape"), p.name, "shape", ctx);
    p.material = lookupMaterial(po, mats, -1);
    out.push_back(std::move(p));
  }
  return out;
}

// "shutter_transforms": [T at the shutter's open, T at its close] (MeshDesc::shutterXf,
// AggregateDesc::shutterXf).
std::pair<Transform, Transform> parseShutterTransforms(const json& st, const std::string& label) {
  if (!st.is_array() || st.size() != 2)
    throw InputError(label, "shutter_transforms",
                     "expected [transform at open, transform at close], got " + describe(st));
  return std::make_pair(parseTransform(st[0], label, "shutter_transforms"),
                        parseTransform(st[1], label, "shutter_transforms"));
}

// A mesh's transforms at the shutter's open and close, checked as validateSceneDesc checks
// its transform (affine, invertible, world points within range), named by the JSON key.
// A mesh that is bad in itself is left to validateSceneDesc, which names what is wrong.
void checkShutterTransforms(const MeshDesc& m) {
  SceneDesc one;
  MeshDesc& copy = one.meshes.emplace_back();
  copy.name = m.name;
  copy.mesh = m.mesh;
  try {
    validateSceneDesc(one);
  } catch (const InputError&) {
    return;
  }
  for (const Transform* xf : {&m.shutterXf->first, &m.shutterXf->second}) {
    copy.xf = *xf;
    try {
      validateSceneDesc(one);
    } catch (const InputError& e) {
      throw InputError(m.name, "shutter_transforms", bareMessage(e));
    }
  }
}

void parseMeshes(const json& v, SceneDesc& desc, const MaterialIndex& mats, const Context& ctx) {
  std::set<std::string> seen;
  const json& a = toArray(v, "scene", "meshes");
  for (size_t i = 0; i < a.size(); ++i) {
    std::string label = itemLabel(a[i], "meshes", i);
    Obj o(a[i], "meshes", str("[", i, "]"), label,
          {"name", "shape", "material", "transform", "visible", "shutter_transforms"});
    checkUnique(seen, label, "meshes", i);
    MeshDesc m;
    m.name = label;
    m.mesh = parseShape(o.required("shape"), label, "shape", ctx);
    m.material = lookupMaterial(o, mats, -1);
    if (const json* t = o.find("transform")) m.xf = parseTransform(*t, label, "transform");
    m.visible = o.flag("visible", true);
    // Transform motion blur (MeshDesc::shutterXf).
    if (const json* st = o.find("shutter_transforms")) {
      m.shutterXf = parseShutterTransforms(*st, label);
      checkShutterTransforms(m);
    }
    desc.meshes.push_back(std::move(m));
  }
}

// A light's "light_link": the objects it lights by name, every one unless "include" lists
// them, less those "exclude" lists (UsdCollectionAPI's includes and excludes); its
// "shadow_link" likewise the objects that cast shadows from it.
struct JsonLightLink {
  size_t light;
  std::optional<std::vector<std::string>> include;
  std::vector<std::string> exclude;
  std::string key;  // light_link, shadow_link
};

std::vector<std::string> toNames(const json& v, const std::string& obj, const std::string& key) {
  const json& a = toArray(v, obj, key);
  std::vector<std::string> names;
  for (const json& n : a) names.push_back(toString(n, obj, key));
  return names;
}

JsonLightLink parseLightLink(const json& v, size_t light, const std::string& label, const std::string& key) {
  Obj o(v, label, key, label, {"include", "exclude"});
  JsonLightLink link{light, std::nullopt, {}, key};
  if (const json* in = o.find("include")) link.include = toNames(*in, label, key + ".include");
  if (const json* ex = o.find("exclude")) link.exclude = toNames(*ex, label, key + ".exclude");
  return link;
}

// Links as core holds them (LightDesc::lightLink, shadowLink): the light's name (its shadow
// link's "name:shadow") as the category of each object it lights (that casts shadows from
// it). A name that is no mesh, aggregate or instanced grains is an error.
void applyLightLinks(const std::vector<JsonLightLink>& links, SceneDesc& desc) {
  for (const JsonLightLink& link : links) {
    LightDesc& light = desc.lights[link.light];
    const bool shadow = link.key == "shadow_link";
    const std::string category = shadow ? light.name + ":shadow" : light.name;
    std::set<std::string> known;
    auto object = [&](const std::string& name, std::vector<std::string>& categories) {
      known.insert(name);
      const bool in = !link.include || std::count(link.include->begin(), link.include->end(), name);
      if (in && !std::count(link.exclude.begin(), link.exclude.end(), name)) categories.push_back(category);
    };
    for (MeshDesc& m : desc.meshes) object(m.name, m.linkCategories);
    for (AggregateDesc& a : desc.aggregates) object(a.name, a.linkCategories);
    for (InstancedGrainsDesc& g : desc.instancedGrains) object(g.name, g.linkCategories);
    for (const auto* names : {link.include ? &*link.include : nullptr, &link.exclude})
      for (size_t k = 0; names && k < names->size(); ++k)
        if (!known.count((*names)[k]))
          throw InputError(light.name, str(link.key, ".", names == &link.exclude ? "exclude" : "include"),
                           str("\"", (*names)[k], "\" is no mesh, aggregate or instanced grains of the scene"));
    (shadow ? light.shadowLink : light.lightLink) = category;
  }
}

void parseLights(const json& v, SceneDesc& desc, const Context& ctx, std::vector<JsonLightLink>& links) {
  std::set<std::string> seen;
  const json& a = toArray(v, "scene", "lights");
  for (size_t i = 0; i < a.size(); ++i) {
    std::string label = itemLabel(a[i], "lights", i);
    if (!a[i].is_object()) throw InputError("lights", str("[", i, "]"), "expected an object, got " + describe(a[i]));
    if (!a[i].contains("type"))
      throw InputError(label, "type", "is required (distant, sphere, rect, disk, cylinder, mesh or dome)");
    std::string type = toString(a[i].at("type"), label, "type");
    std::vector<std::string> keys = {"name",      "type",      "color",     "intensity",
                                     "exposure",  "normalize", "transform", "light_link",
                                     "shadow_link", "shadows"};
    const std::vector<std::string> shapingKeys = {"shaping_cone_angle",     "shaping_cone_softness",
                                                  "shaping_focus",          "shaping_focus_tint",
                                                  "shaping_ies_file",       "shaping_ies_angle_scale",
                                                  "shaping_ies_normalize"};
    LightDesc l;
    if (type == "distant") {
      l.type = LightType::Distant;
      keys.insert(keys.end(), {"direction", "angle"});
    } else if (type == "sphere") {
      l.type = LightType::Sphere;
      keys.insert(keys.end(), {"position", "radius"});
    } else if (type == "rect") {
      l.type = LightType::Rect;
      keys.insert(keys.end(), {"width", "height"});
    } else if (type == "disk") {
      l.type = LightType::Disk;
      keys.push_back("radius");
    } else if (type == "cylinder") {
      l.type = LightType::Cylinder;
      keys.insert(keys.end(), {"position", "radius", "length"});
    } else if (type == "dome") {
      l.type = LightType::Dome;
      keys.push_back("texture_file");
    } else if (type == "mesh") {
      l.type = LightType::Mesh;
      keys.insert(keys.end(), {"shape", "double_sided"});
    } else {
      throw InputError(label, "type",
                       str("unknown light type \"", type,
                           "\" (expected distant, sphere, rect, disk, cylinder, mesh or dome)"));
    }
    if (l.type != LightType::Distant && l.type != LightType::Dome && l.type != LightType::Mesh)
      keys.insert(keys.end(), shapingKeys.begin(), shapingKeys.end());
    Obj o(a[i], "lights", str("[", i, "]"), label, keys);
    checkUnique(seen, label, "lights", i);
    l.name = label;
    const char* placement = l.type == LightType::Distant ? "direction" : "position";
    if (o.has("transform") && o.has(placement))
      throw InputError(label, placement, "give either transform or " + std::string(placement) + ", not both");
    if (const json* t = o.find("transform")) l.xf = parseTransform(*t, label, "transform");
    if (const json* d = o.find("direction")) {
      Vec3 dir = toVec3(*d, label, "direction");
      if (isBlack(dir)) throw InputError(label, "direction", "is zero");
      // Local -Z (the USD emission axis) is mapped onto the travel direction.
      l.xf = Transform::lookAt(Vec3(0.0f), dir, Vec3(0, 1, 0));
    }
    if (const json* p = o.find("position")) l.xf = Transform::translate(toVec3(*p, label, "position"));
    l.color = o.vec3("color", l.color, true);
    l.intensity = o.num("intensity", l.intensity);
    l.exposure = o.num("exposure", l.exposure);
    l.normalize = o.flag("normalize", l.normalize);
    l.angle = o.num("angle", l.angle);
    l.radius = o.num("radius", l.radius);
    l.width = o.num("width", l.width);
    l.height = o.num("height", l.height);
    l.length = o.num("length", l.length);
    if (l.type == LightType::Mesh) {  // a mesh's shape, emitting from its front faces
      l.mesh = parseShape(o.required("shape"), label, "shape", ctx);
      l.doubleSided = o.flag("double_sided", false);
    }
    for (const std::string& k : shapingKeys) l.shaping.enabled = l.shaping.enabled || o.has(k);
    l.shaping.coneAngle = o.num("shaping_cone_angle", l.shaping.coneAngle);
    l.shaping.coneSoftness = o.num("shaping_cone_softness", l.shaping.coneSoftness);
    l.shaping.focus = o.num("shaping_focus", l.shaping.focus);
    l.shaping.focusTint = o.vec3("shaping_focus_tint", l.shaping.focusTint, true);
    l.shaping.iesAngleScale = o.num("shaping_ies_angle_scale", l.shaping.iesAngleScale);
    l.shaping.iesNormalize = o.flag("shaping_ies_normalize", l.shaping.iesNormalize);
    for (auto [key, file] : {std::pair{"shaping_ies_file", &l.shaping.iesFile}, std::pair{"texture_file", &l.textureFile}})
      if (const json* f = o.find(key)) {
        const std::string name = toString(*f, label, key);
        if (!name.empty()) *file = existingFile(ctx, name, label, key);
      }
    l.shadows = o.flag("shadows", l.shadows);
    for (const char* key : {"light_link", "shadow_link"})
      if (const json* link = o.find(key)) links.push_back(parseLightLink(*link, desc.lights.size(), label, key));
    desc.lights.push_back(std::move(l));
  }
}

void parseAggregates(const json& v, SceneDesc& desc, const MaterialIndex& mats, const Context& ctx) {
  std::set<std::string> seen;
  const json& a = toArray(v, "scene", "aggregates");
  for (size_t i = 0; i < a.size(); ++i) {
    std::string label = itemLabel(a[i], "aggregates", i);
    Obj o(a[i], "aggregates", str("[", i, "]"), label,
          {"name", "boundary", "transform", "grain_radius", "packing_rate", "seed", "tile_spheres", "prototypes",
           "weights", "sizes", "size_spread", "shutter_transforms"});
    checkUnique(seen, label, "aggregates", i);
    AggregateDesc ag;
    ag.name = label;
    ag.boundary = parseShape(o.required("boundary"), label, "boundary", ctx);
    if (const json* t = o.find("transform")) ag.xf = parseTransform(*t, label, "transform");
    ag.grainRadius = o.num("grain_radius", ag.grainRadius);
    ag.packingRate = o.num("packing_rate", ag.packingRate);
    ag.seed = o.u64("seed", ag.seed);
    ag.tileSpheres = o.integer("tile_spheres", ag.tileSpheres);
    ag.prototypes = parsePrototypes(o.required("prototypes"), label, mats, ctx);
    if (const json* w = o.find("weights"))
      ag.weights = toFloats(*w, label, "weights");
    else
      ag.weights.assign(ag.prototypes.size(), 1.0f);
    // Polydisperse grains: each prototype's radius relative to grain_radius, and a spread.
    if (const json* z = o.find("sizes")) ag.sizes = toFloats(*z, label, "sizes");
    ag.sizeSpread = o.num("size_spread", ag.sizeSpread);
    // Transform motion blur, as a mesh's (AggregateDesc::shutterXf), checked under this key.
    if (const json* st = o.find("shutter_transforms")) {
      ag.shutterXf = parseShutterTransforms(*st, label);
      // An aggregate bad in itself is left to validateSceneDesc, which names what is wrong.
      bool valid = true;
      try {
        validateAggregateParameters(ag, label);
      } catch (const InputError&) {
        valid = false;
      }
      try {
        if (valid) validateAggregateMotion(ag, label);
      } catch (const InputError& e) {
        throw InputError(label, "shutter_transforms", bareMessage(e));
      }
    }
    desc.aggregates.push_back(std::move(ag));
  }
}

// [[w, x, y, z], ...]: unit quaternions (USD's quath order: real part first).
std::vector<Quat> parseQuats(const json& v, const std::string& obj, const std::string& key) {
  std::vector<Quat> out;
  for (const json& e : toArray(v, obj, key)) {
    if (!e.is_array() || e.size() != 4) throw InputError(obj, key, "expected [w, x, y, z] quaternions, got " + describe(e));
    out.push_back({toFloat(e[0], obj, key), toFloat(e[1], obj, key), toFloat(e[2], obj, key), toFloat(e[3], obj, key)});
  }
  return out;
}

// Simulated grains, as a UsdGeomPointInstancer with GranularInstancedAggregateAPI holds them
// (InstancedGrainsDesc): per-grain arrays in the instancer's space, prototypes by index.
// Lengths, unit orientations, scales, indices and finiteness are validateInstancedGrains'
// (through validateSceneDesc), named <name>.<key>.
void parseInstancedGrains(const json& v, SceneDesc& desc, const MaterialIndex& mats, const Context& ctx) {
  std::set<std::string> seen;
  const json& a = toArray(v, "scene", "instanced_grains");
  for (size_t i = 0; i < a.size(); ++i) {
    std::string label = itemLabel(a[i], "instanced_grains", i);
    Obj o(a[i], "instanced_grains", str("[", i, "]"), label,
          {"name", "transform", "prototypes", "positions", "orientations", "scales", "proto_indices", "velocities",
           "angular_velocities"});
    checkUnique(seen, label, "instanced_grains", i);
    InstancedGrainsDesc g;
    g.name = label;
    if (const json* t = o.find("transform")) g.xf = parseTransform(*t, label, "transform");
    g.prototypes = parsePrototypes(o.required("prototypes"), label, mats, ctx);
    g.positions = parsePoints(o.required("positions"), label, "positions");
    const std::vector<int> indices = parseInts(o.required("proto_indices"), label, "proto_indices");
    g.protoIndices.assign(indices.begin(), indices.end());
    if (const json* q = o.find("orientations")) g.orientations = parseQuats(*q, label, "orientations");
    if (const json* z = o.find("scales")) g.scales = toFloats(*z, label, "scales");
    if (const json* w = o.find("velocities")) g.velocities = parsePoints(*w, label, "velocities");
    if (const json* w = o.find("angular_velocities")) g.angularVelocities = parsePoints(*w, label, "angular_velocities");
    desc.instancedGrains.push_back(std::move(g));
  }
}

// Nested object-key path of the parser's position, for duplicate-key messages.
struct KeyTracker {
  std::vector<std::set<std::string>> keys;
  std::vector<std::string> current;
  std::string path() const {
    std::string p;
    for (size_t i = 0; i + 1 < current.size(); ++i) p += (p.empty() ? "" : ".") + current[i];
    return p.empty() ? "the top level" : p;
  }
};

std::string parseErrorDetail(const std::string& what) {
  // nlohmann: "[json.exception.parse_error.101] parse error at line 1, column 2: <detail>"
  size_t p = what.find("parse error");
  if (p == std::string::npos) return what;
  size_t c = what.find(": ", p);
  return c == std::string::npos ? what : what.substr(c + 2);
}

}  // namespace

TriangleMesh loadObj(const std::string& path, const std::string& object) {
  std::ifstream in(path);
  if (!in) throw InputError(object, "obj", str("cannot open \"", path, "\""));
  std::vector<Vec3> pts;
  struct Face {
    std::vector<long long> idx;
    size_t line;
  };
  std::vector<Face> faces;
  std::string line;
  size_t lineNo = 0;
  auto fail = [&](const std::string& msg) { throw InputError(object, "obj", str(path, ":", lineNo, ": ", msg)); };
  while (std::getline(in, line)) {
    ++lineNo;
    std::istringstream ss(line);
    std::string tag;
    if (!(ss >> tag)) continue;
    if (tag == "v") {
      float c[3];
      for (float& x : c) {
        std::string tok;
        if (!(ss >> tok)) fail("a vertex needs 3 coordinates");
        char* end = nullptr;
        errno = 0;
        x = std::strtof(tok.c_str(), &end);
        if (end == tok.c_str() || *end != '\0' || errno == ERANGE || !std::isfinite(x))
          fail(str("\"", printableToken(tok), "\" is not a finite number"));
      }
      pts.push_back({c[0], c[1], c[2]});
    } else if (tag == "f") {
      Face f{{}, lineNo};
      std::string tok;
      while (ss >> tok) {
        // v, v/vt, v//vn, v/vt/vn: only the position index matters here.
        std::string vs = tok.substr(0, tok.find('/'));
        char* end = nullptr;
        errno = 0;
        long long k = std::strtoll(vs.c_str(), &end, 10);
        if (vs.empty() || *end != '\0' || errno == ERANGE) fail(str("\"", printableToken(tok), "\" is not a vertex index"));
        if (k == 0) fail("vertex index 0 is invalid (OBJ indices start at 1)");
        // Negative indices count back from the latest vertex defined so far.
        f.idx.push_back(k > 0 ? k - 1 : (long long)pts.size() + k);
        if (f.idx.back() < 0) fail(str("vertex index ", k, " refers before the first vertex"));
      }
      if (f.idx.size() < 3) fail(str("a face needs at least 3 vertices, got ", f.idx.size()));
      faces.push_back(std::move(f));
    }
  }
  if (faces.empty()) throw InputError(object, "obj", str("\"", path, "\" has no faces"));
  TriangleMesh m;
  m.points = pts;
  for (const Face& f : faces) {
    for (long long k : f.idx)
      if (k >= (long long)pts.size()) {
        lineNo = f.line;
        fail(str("vertex index ", k + 1, " is out of range (", pts.size(), " vertices)"));
      }
    for (size_t k = 1; k + 1 < f.idx.size(); ++k)
      for (long long v : {f.idx[0], f.idx[k], f.idx[k + 1]}) m.indices.push_back(uint32_t(v));
  }
  return m;
}

SceneDesc parseSceneJson(const std::string& text, const std::string& sourceName) {
  json root;
  KeyTracker tracker;
  json::parser_callback_t onEvent = [&](int, json::parse_event_t ev, json& parsed) {
    switch (ev) {
      case json::parse_event_t::object_start:
        tracker.keys.emplace_back();
        tracker.current.emplace_back();
        break;
      case json::parse_event_t::object_end:
        tracker.keys.pop_back();
        tracker.current.pop_back();
        break;
      case json::parse_event_t::key: {
        // nlohmann silently keeps the last of duplicate keys; a scene file that sets
        // a value twice is almost certainly a mistake.
        std::string k = parsed.get<std::string>();
        tracker.current.back() = k;
        if (!tracker.keys.back().insert(k).second)
          throw InputError(sourceName, "", str("duplicate key \"", k, "\" in ", tracker.path()));
        break;
      }
      default: break;
    }
    return true;
  };
  try {
    root = json::parse(text, onEvent, /*allow_exceptions=*/true, /*ignore_comments=*/true);
  } catch (const json::parse_error& e) {
    size_t byte = e.byte, line = 1, col = 1;
    for (size_t i = 0; i + 1 < byte && i < text.size(); ++i) {
      if (text[i] == '\n') ++line, col = 1;
      else ++col;
    }
    throw InputError(sourceName, "",
                     str("JSON parse error at byte ", byte, " (line ", line, ", column ", col, "): ",
                         parseErrorDetail(e.what())));
  }
  catch (const json::exception& e) {
    // A number beyond the range of a double (1e400) is an out_of_range error, not a
    // parse_error, raised while its value is read: name the key being read (the JSON
    // fuzzer's finding; it escaped as a nlohmann exception, exit 1).
    std::string w = e.what();
    size_t b = w.find("] ");
    std::string detail = b == std::string::npos ? w : w.substr(b + 2);
    std::string object = "scene", attribute;
    for (const std::string& k : tracker.current) {
      if (k.empty()) continue;
      if (!attribute.empty()) object = attribute;
      attribute = k;
    }
    throw InputError(object, attribute, str(detail, " (beyond the range of a double)"));
  }

  SceneDesc desc;
  try {
    Context ctx;
    ctx.base = fs::path(sourceName).parent_path();
    Obj top(root, sourceName, "", "scene",
            {"render", "camera", "materials", "meshes", "lights", "aggregates", "instanced_grains"});
    bool motionBlur = true;
    if (const json* r = top.find("render")) {
      Obj ro(*r, "scene", "render", "render", {"width", "height", "spp", "seed", "max_depth", "rr_depth", "threads", "technique", "bundle_size", "tau", "explicit_bounces", "da_depth_factor", "da_min_order", "da_instanced", "roulette", "lod", "proxies", "medium_model", "default_light", "physical_sun", "sun_regularization", "switch_for_view", "crop", "motion_blur"});
      parseRender(ro, desc.settings);
      motionBlur = ro.flag("motion_blur", true);
    }
    if (const json* c = top.find("camera"))
      parseCamera(Obj(*c, "scene", "camera", "camera",
                      {"look_at", "transform", "focal_length", "horizontal_aperture", "vertical_aperture",
                       "horizontal_aperture_offset", "vertical_aperture_offset", "clipping_range", "f_stop",
                       "focus_distance", "shutter_open", "shutter_close"}),
                  desc.camera);
    MaterialIndex mats;
    if (const json* m = top.find("materials")) parseMaterials(*m, desc, mats, ctx);
    if (const json* m = top.find("meshes")) parseMeshes(*m, desc, mats, ctx);
    std::vector<JsonLightLink> links;
    if (const json* l = top.find("lights")) parseLights(*l, desc, ctx, links);
    if (const json* a = top.find("aggregates")) parseAggregates(*a, desc, mats, ctx);
    if (const json* g = top.find("instanced_grains")) parseInstancedGrains(*g, desc, mats, ctx);
    applyLightLinks(links, desc);
    if (!motionBlur) stillFrame(desc);
  } catch (const json::exception& e) {
    // Converters check types before every get<>(), so this is a safety net only.
    throw InputError(sourceName, "", str("unexpected JSON error: ", e.what()));
  }
  // The desc speaks USD attribute names; report them as the JSON keys the user wrote.
  try {
    validateSceneDesc(desc);
  } catch (const InputError& e) {
    throw InputError(e.object(), camelToSnake(e.attribute()), bareMessage(e));
  }
  return desc;
}

SceneDesc loadSceneJson(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path, "", "cannot open the scene file");
  std::ostringstream ss;
  ss << in.rdbuf();
  if (in.bad()) throw InputError(path, "", "cannot read the scene file");
  return parseSceneJson(ss.str(), path);
}

}  // namespace granular
