// granular_prims.cpp — the granular schema's meaning (granular_prims.h): which prims are
// aggregates, prototypes and ordinary meshes, the schema's fallbacks and every check, with
// errors in USD terms. Ranges are checked by scene_desc.cpp's validators, so that the JSON
// and USD front ends agree; only their names are translated here.
#include "granular_prims.h"

#include <algorithm>
#include <cctype>
#include <climits>
#include <cmath>
#include <set>
#include <type_traits>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

// Half-float USD arrays read in place: Imath's conversion, header-only (core links no libImath).
#define IMATH_HALF_NO_LOOKUP_TABLE
#include <Imath/half.h>

#include "error.h"
#include "usd_lights.h"

namespace granular {

namespace {

const char* const kAggregatePrimvars[] = {"grainRadius", "packingRate", "prototypes", "weights",
                                          "seed",        "tileSpheres", "sizes",      "sizeSpread"};
const char* const kGrainPrimvars[] = {"ior", "absorption", "roughness"};

std::string usdName(const std::string& base) { return kGranularNamespace + base; }

// The prim a value's error names: where it was authored (an ancestor, when inherited),
// else the prim itself (a fallback).
const std::string& sourceOf(const MeshPrim& prim, const std::string& base) {
  auto it = prim.granular.find(base);
  return it != prim.granular.end() && !it->second.source.empty() ? it->second.source : prim.path;
}

// ---- typed values -------------------------------------------------------------------------

enum class Kind { Float, Int, FloatArray, StringArray, Color3 };

const char* kindName(Kind k) {
  switch (k) {
    case Kind::Float: return "float";
    case Kind::Int: return "int";
    case Kind::FloatArray: return "float[]";
    case Kind::StringArray: return "string[]";
    case Kind::Color3: return "color3f";
  }
  return "?";
}

// The schema's types and the authored types that stand for them (schemas/README.md).
bool typeAccepted(Kind k, const std::string& t) {
  auto among = [&t](std::initializer_list<const char*> names) {
    return std::any_of(names.begin(), names.end(), [&t](const char* n) { return t == n; });
  };
  switch (k) {
    case Kind::Float: return among({"float", "double", "half"});
    case Kind::Int: return among({"int", "int64", "uint", "uint64", "uchar"});
    case Kind::FloatArray: return among({"float[]", "double[]", "half[]"});
    case Kind::StringArray: return t == "string[]";
    case Kind::Color3: return among({"color3f", "color3d", "color3h", "float3", "double3", "half3", "vector3f"});
  }
  return false;
}

std::string describe(const PrimvarValue& v) { return describeUsdValue(v); }

bool shapeFits(Kind k, const PrimvarValue& v) {
  switch (k) {
    case Kind::Float: return !v.isString && !v.isArray && v.numbers.size() == 1;
    case Kind::Int:
      return !v.isString && !v.isArray && v.numbers.size() == 1 && std::isfinite(v.numbers[0]) &&
             std::floor(v.numbers[0]) == v.numbers[0];
    case Kind::FloatArray: return !v.isString && v.isArray && v.strings.empty();
    case Kind::StringArray: return v.isString && v.isArray && v.numbers.empty();
    case Kind::Color3: return !v.isString && !v.isArray && v.numbers.size() == 3;
  }
  return false;
}

// The prim's value of a granular primvar, checked to be of kind k; null when absent.
const PrimvarValue* typed(const MeshPrim& prim, const std::string& base, Kind k) {
  auto it = prim.granular.find(base);
  if (it == prim.granular.end()) return nullptr;
  const PrimvarValue& v = it->second;
  const std::string& src = sourceOf(prim, base);
  if (!typeAccepted(k, v.typeName))
    throw InputError(src, usdName(base), str("has type ", v.typeName, ", expected ", kindName(k)));
  if (v.interpolation != "constant")
    throw InputError(src, usdName(base), str("has interpolation ", v.interpolation, ", expected constant"));
  if (!shapeFits(k, v)) throw InputError(src, usdName(base), str("has value ", describe(v), ", expected a ", kindName(k)));
  return &v;
}

int64_t toInt64(double v) {
  // Integral by now; clamped so that out-of-range values stay out of range, not undefined.
  if (v >= 9.2e18) return INT64_MAX;
  if (v <= -9.2e18) return INT64_MIN;
  return int64_t(v);
}

bool hasApi(const MeshPrim& prim, const char* api) {
  return prim.apiSchemas && std::find(prim.apiSchemas->begin(), prim.apiSchemas->end(), api) != prim.apiSchemas->end();
}

template <size_t N>
bool hasAnyOf(const MeshPrim& prim, const char* const (&names)[N]) {
  return std::any_of(std::begin(names), std::end(names), [&](const char* n) { return prim.granular.count(n) > 0; });
}

bool anyGrainPrimvar(const MeshPrim& prim) { return hasAnyOf(prim, kGrainPrimvars); }

// ---- SdfPath syntax -----------------------------------------------------------------------
// Enough of SdfPath's grammar to tell a prim path from any other path and to say, in
// SdfPath's words, where a malformed one goes wrong (core has no USD to ask).

struct ParsedPath {
  bool absolute = false;
  bool primPath = false;
  int up = 0;            // leading ".." of a relative path
  std::string elements;  // the prim elements after the leading "/" or "../", e.g. "Grains/Round"
};

struct PathSyntaxError {
  std::string why;
};

class PathParser {
 public:
  explicit PathParser(const std::string& text) : t_(text) {}

  ParsedPath parse() {
    ParsedPath r;
    if (at('/')) {
      r.absolute = true;
      ++i_;
      if (end()) return r;  // the absolute root: not a prim
      if (!identStart()) fail("expected end of path");
      primElements(r);
    } else if (at('.')) {
      if (t_.compare(i_, 2, "..") == 0) {
        while (t_.compare(i_, 2, "..") == 0) {
          i_ += 2;
          ++r.up;
          if (end()) {
            r.primPath = true;
            return r;
          }
          if (!at('/')) fail("expected end of path");
          ++i_;
          if (end()) fail("expected prim name");
        }
        if (at('.')) return property(r);
        if (!identStart()) fail("expected prim name");
        primElements(r);
      } else {
        ++i_;
        if (end()) {
          r.primPath = true;  // "." is the anchor itself
          return r;
        }
        if (!identStart()) fail("expected property name after '.'");
        --i_;
        return property(r);
      }
    } else if (!end() && identStart()) {
      primElements(r);
    } else {
      fail("expected a path beginning with '/', '.', or a prim name");
    }
    return r;
  }

 private:
  bool end() const { return i_ >= t_.size(); }
  bool at(char c) const { return !end() && t_[i_] == c; }
  bool identStart() const {
    unsigned char c = static_cast<unsigned char>(t_[i_]);
    return std::isalpha(c) || c == '_' || c >= 0x80;  // UTF-8 identifiers, as USD allows
  }
  bool identChar() const {
    unsigned char c = static_cast<unsigned char>(t_[i_]);
    return std::isalnum(c) || c == '_' || c >= 0x80;
  }
  bool variantChar() const {
    unsigned char c = static_cast<unsigned char>(t_[i_]);
    return std::isalnum(c) || c == '_' || c == '|' || c == '-';
  }
  void identifier() {
    while (!end() && identChar()) ++i_;
  }

  [[noreturn]] void fail(const std::string& expected) const {
    std::string where = str("at character ", i_ + 1);
    if (!end()) where += str(" ('", t_[i_], "')");
    throw PathSyntaxError{str("Ill-formed SdfPath <", t_, "> ", where, ": ", expected)};
  }

  void primElements(ParsedPath& r) {
    size_t start = i_;
    for (;;) {
      if (end() || !identStart()) fail("expected prim name");
      identifier();
      while (at('{')) {
        variantSelection();
        if (!end() && identStart()) identifier();  // a child inside the variant
      }
      if (end()) {
        r.primPath = t_.back() != '}';  // "/A{v=x}" selects a variant: no prim path
        r.elements = t_.substr(start);
        return;
      }
      if (at('/')) {
        ++i_;
        continue;
      }
      if (at('.')) {
        r.elements = t_.substr(start, i_ - start);
        property(r);
        return;
      }
      fail("expected end of path");
    }
  }

  void variantSelection() {
    ++i_;  // '{'
    size_t s = i_;
    while (!end() && variantChar()) ++i_;
    if (i_ == s) fail("expected variant set name after '{'");
    if (!at('=')) fail("expected '=' after variant set name");
    ++i_;
    if (at('.')) ++i_;
    while (!end() && variantChar()) ++i_;
    if (!at('}')) fail("expected variant set name or '}' to close variant selection");
    ++i_;
  }

  void namespacedName() {
    if (end() || !identStart()) fail("expected property name after '.'");
    identifier();
    while (at(':')) {
      ++i_;
      if (end() || !identStart()) fail("expected identifier after ':'");
      identifier();
    }
  }

  void targetPath() {
    int depth = 0;
    for (; !end(); ++i_) {
      if (t_[i_] == '[') ++depth;
      if (t_[i_] == ']' && --depth == 0) {
        ++i_;
        return;
      }
    }
    fail("expected ']' to close target path");
  }

  // A property path (never a prim path): ".name", then "[target]" and ".name",
  // ".mapper[target]" or ".expression".
  ParsedPath property(ParsedPath& r) {
    r.primPath = false;
    ++i_;  // '.'
    namespacedName();
    if (end()) return r;
    if (at('[')) {
      targetPath();
      if (end()) return r;
      if (!at('.')) fail("expected end of path");
      ++i_;
      namespacedName();
    } else if (at('.')) {
      ++i_;
      if (t_.compare(i_, 6, "mapper") == 0) {
        i_ += 6;
        if (!at('[')) fail("expected target path after 'mapper'");
        targetPath();
      } else if (t_.compare(i_, 10, "expression") == 0) {
        i_ += 10;
      } else {
        fail("expected 'mapper' or 'expression' after '.'");
      }
    }
    if (!end()) fail("expected end of path");
    return r;
  }

  const std::string& t_;
  size_t i_ = 0;
};

std::vector<std::string> splitPrimPath(const std::string& path) {
  std::vector<std::string> out;
  size_t i = 0;
  while (i < path.size()) {
    size_t j = path.find('/', i);
    if (j == std::string::npos) j = path.size();
    if (j > i) out.push_back(path.substr(i, j - i));
    i = j + 1;
  }
  return out;
}

// ---- assembly ----------------------------------------------------------------------------

// Runs check (core's validation of what was built from prim) and renames the attributes
// that came from granular primvars to theirs, at the prim they were authored on.
template <typename F>
void inUsdTerms(const MeshPrim& prim, F&& check) {
  try {
    check();
  } catch (const InputError& e) {
    if (e.object() == prim.path && (isAggregatePrimvar(e.attribute()) || isGrainPrimvar(e.attribute())))
      throw InputError(sourceOf(prim, e.attribute()), usdName(e.attribute()), e.detail());
    throw;
  }
}

// A grain prototype's material: its grain values appended to desc (when it has the API or
// any of its primvars), else the front end's (MeshPrim::material, -1: clear glass).
int appendGrainMaterial(const MeshPrim& proto, SceneDesc& desc) {
  if (!(hasApi(proto, kGrainApi) || anyGrainPrimvar(proto))) return proto.material;
  GrainValues g = readGrainValues(proto);
  const std::string& src = sourceOf(proto, "roughness");
  if (!std::isfinite(g.roughness) || g.roughness < 0 || g.roughness > 1)
    throw InputError(src, usdName("roughness"), str(g.roughness, " is outside [0, 1]"));
  MaterialDesc m;
  m.name = proto.path;
  m.type = MaterialType::Dielectric;
  m.ior = g.ior;
  m.absorption = g.absorption;
  m.roughness = g.roughness;
  inUsdTerms(proto, [&] { validateMaterialDesc(m, proto.path); });
  desc.materials.push_back(m);
  return int(desc.materials.size()) - 1;
}

class Assembler {
 public:
  Assembler(const std::vector<MeshPrim>& prims, SceneDesc& desc, const PrimLookup& lookup)
      : prims_(prims), desc_(desc), lookup_(lookup) {
    for (size_t i = 0; i < prims.size(); ++i) byPath_.emplace(prims[i].path, i);
  }

  void run() {
    std::vector<size_t> aggregates = findAggregates();
    std::set<size_t> isAggregate(aggregates.begin(), aggregates.end());
    for (size_t i : aggregates) addAggregate(prims_[i]);
    for (size_t i = 0; i < prims_.size(); ++i) {
      const MeshPrim& p = prims_[i];
      if (!p.visible || isAggregate.count(i) || prototypes_.count(p.path)) continue;
      if (p.apiSchemas ? hasApi(p, kGrainApi) : anyGrainPrimvar(p)) continue;  // a grain, never drawn
      if (p.light)
        addMeshLight(p);
      else
        addMesh(p);
    }
  }

 private:
  std::vector<size_t> findAggregates() const {
    std::vector<size_t> candidates;
    std::set<std::string> named;
    for (size_t i = 0; i < prims_.size(); ++i) {
      const MeshPrim& p = prims_[i];
      if (!p.visible) continue;
      if (p.apiSchemas) {
        if (hasApi(p, kAggregateApi)) candidates.push_back(i);
        continue;
      }
      // Without API schemas an inherited aggregate primvar may reach a grain: a mesh named
      // as a prototype is not an aggregate. Unreadable entries are reported later.
      if (p.typeName != "Mesh" || !hasAnyOf(p, kAggregatePrimvars) || anyGrainPrimvar(p)) continue;
      candidates.push_back(i);
      try {
        if (const PrimvarValue* v = typed(p, "prototypes", Kind::StringArray))
          for (const std::string& s : v->strings) named.insert(resolvePrototypePath(p.path, s));
      } catch (const InputError&) {
      }
    }
    std::vector<size_t> out;
    for (size_t i : candidates)  // one named as a grain is refused (addAggregate) if it declares itself one
      if (prims_[i].apiSchemas || !named.count(prims_[i].path) || declaresAggregate(prims_[i])) out.push_back(i);
    return out;
  }

  // The prim at an absolute path: listed, else looked up (once); null when there is none.
  const MeshPrim* find(const std::string& path) {
    auto it = byPath_.find(path);
    if (it != byPath_.end()) return &prims_[it->second];
    auto lt = lookedUp_.find(path);
    if (lt == lookedUp_.end()) {
      std::optional<MeshPrim> found;
      MeshPrim p;
      if (lookup_ && lookup_(path, p)) found = std::move(p);
      lt = lookedUp_.emplace(path, std::move(found)).first;
    }
    return lt->second ? &*lt->second : nullptr;
  }

  // Whether a prim is an aggregate in its own right: its API schema where the front end sees
  // it, else a prototypes primvar authored on the prim itself (not inherited).
  static bool declaresAggregate(const MeshPrim& p) {
    if (p.apiSchemas) return hasApi(p, kAggregateApi);
    auto it = p.granular.find("prototypes");
    return it != p.granular.end() && (it->second.source.empty() || it->second.source == p.path);
  }

  void addAggregate(const MeshPrim& prim) {
    const std::string& path = prim.path;
    if (prim.typeName != "Mesh")
      throw InputError(path, "", str(kAggregateApi, " applies to a Mesh, not a ",
                                     prim.typeName.empty() ? "typeless prim" : prim.typeName,
                                     prim.typeName == "PointInstancer"
                                         ? str(" (explicit grains from a simulation: ", kInstancedAggregateApi, ")")
                                         : ""));
    AggregateValues v = readAggregateValues(prim);
    validateClosed(prim.mesh, path);

    const std::string& protoSrc = sourceOf(prim, "prototypes");
    const std::string protoAttr = usdName("prototypes");
    std::vector<const MeshPrim*> protos;
    for (const std::string& text : v.prototypes) {
      std::string p = resolvePrototypePath(path, text);
      std::string what = str("prototype \"", text, "\" (", p, ")");
      const MeshPrim* proto = find(p);
      if (!proto) throw InputError(protoSrc, protoAttr, what + " does not exist");
      if (!proto->active) throw InputError(protoSrc, protoAttr, what + " is inactive");
      if (proto->typeName != "Mesh")
        throw InputError(protoSrc, protoAttr,
                         str(what, " is a ", proto->typeName.empty() ? "typeless prim" : proto->typeName, ", not a Mesh"));
      // A grain is a plain mesh: an aggregate as a grain (itself, or another, which also
      // makes cycles) would be drawn in both roles, or in one by one front end and the other
      // by the other.
      if (p == path) throw InputError(protoSrc, protoAttr, what + " is this aggregate itself");
      if (declaresAggregate(*proto))
        throw InputError(protoSrc, protoAttr,
                         str(what, " is itself an aggregate (", kAggregateApi, "): a grain prototype is a plain mesh"));
      protos.push_back(proto);
    }
    if (protos.empty()) throw InputError(protoSrc, protoAttr, "is empty (at least one grain prototype mesh is needed)");
    std::vector<float> weights = v.weights.empty() ? std::vector<float>(protos.size(), 1.0f) : v.weights;
    if (weights.size() != protos.size())
      throw InputError(sourceOf(prim, "weights"), usdName("weights"),
                       str("has ", weights.size(), " entries but there are ", protos.size(), " prototypes"));
    if (v.seed < 0) throw InputError(sourceOf(prim, "seed"), usdName("seed"), str(v.seed, " must be >= 0"));

    std::vector<GrainPrototypeDesc> grains;
    for (const MeshPrim* proto : protos) {
      prototypes_.insert(proto->path);
      validateClosed(proto->mesh, proto->path);
      GrainPrototypeDesc g;
      g.name = proto->path;
      g.mesh = proto->mesh;
      g.material = grainMaterial(*proto);
      grains.push_back(std::move(g));
    }

    AggregateDesc a;
    a.name = path;
    a.boundary = prim.mesh;
    a.prototypes = std::move(grains);
    a.weights = std::move(weights);
    a.grainRadius = v.grainRadius;
    a.packingRate = v.packingRate;
    a.seed = uint64_t(v.seed);
    a.tileSpheres = int(std::clamp<int64_t>(v.tileSpheres, INT_MIN, INT_MAX));
    a.sizes = v.sizes;
    a.sizeSpread = v.sizeSpread;
    a.id = prim.id;
    std::vector<Transform> xfs = prim.instances.empty() ? std::vector<Transform>(1) : prim.instances;
    checkInstanceIds(prim, xfs.size());
    for (size_t k = 0; k < xfs.size(); ++k) {
      const Transform& xf = xfs[k];
      a.xf = xf;
      a.linkCategories = linkCategoriesOf(prim, k);
      a.instanceId = prim.instanceIds.empty() ? -1 : prim.instanceIds[k];
      inUsdTerms(prim, [&] { validateAggregateParameters(a, path); });
      desc_.aggregates.push_back(a);
    }
  }

  // The material of a grain prototype (grain values, else the front end's), once per prim.
  int grainMaterial(const MeshPrim& proto) {
    auto it = grainMaterials_.find(proto.path);
    if (it != grainMaterials_.end()) return it->second;
    int index = appendGrainMaterial(proto, desc_);
    grainMaterials_.emplace(proto.path, index);
    return index;
  }

  // One instance index per instance (or none), each >= 0.
  static void checkInstanceIds(const MeshPrim& prim, size_t instances) {
    if (prim.instanceIds.empty()) return;
    if (prim.instanceIds.size() != instances)
      throw InputError(prim.path, "instanceIds", str(prim.instanceIds.size(), " instance indices for ", instances,
                                                     " instances"));
    for (int i : prim.instanceIds)
      if (i < 0) throw InputError(prim.path, "instanceIds", str(i, " is not an instance index (>= 0)"));
  }

  // The light-link categories of instance k: the prim's and the instance's own. A list per
  // instance or none.
  static std::vector<std::string> linkCategoriesOf(const MeshPrim& prim, size_t k) {
    const size_t instances = prim.instances.empty() ? 1 : prim.instances.size();
    if (!prim.instanceLinkCategories.empty() && prim.instanceLinkCategories.size() != instances)
      throw InputError(prim.path, "instanceCategories",
                       str(prim.instanceLinkCategories.size(), " category lists for ", instances, " instances"));
    std::vector<std::string> c = prim.linkCategories;
    if (!prim.instanceLinkCategories.empty())
      c.insert(c.end(), prim.instanceLinkCategories[k].begin(), prim.instanceLinkCategories[k].end());
    return c;
  }

  void addMesh(const MeshPrim& prim) {
    int material = prim.material;
    if (material < 0 && prim.displayColor) {
      MaterialDesc m;
      m.name = prim.path + ".displayColor";
      m.type = MaterialType::Lambert;
      m.albedo = *prim.displayColor;
      desc_.materials.push_back(m);
      material = int(desc_.materials.size()) - 1;
    }
    std::vector<Transform> xfs = prim.instances.empty() ? std::vector<Transform>(1) : prim.instances;
    checkInstanceIds(prim, xfs.size());
    for (size_t k = 0; k < xfs.size(); ++k) {
      MeshDesc d;
      d.name = prim.path;
      d.mesh = prim.mesh;
      d.xf = xfs[k];
      d.material = material;
      d.id = prim.id;
      d.linkCategories = linkCategoriesOf(prim, k);
      d.instanceId = prim.instanceIds.empty() ? -1 : prim.instanceIds[k];
      desc_.meshes.push_back(std::move(d));
    }
  }

  // A surface with MeshLightAPI: a mesh light per instance, the mesh its body (not drawn
  // as a surface as well), its colour tinted by the bound material's emission where
  // MeshLightAPI's materialSyncMode asks (LightDesc::tintByMaterial) and that emission is
  // a colour, not black.
  void addMeshLight(const MeshPrim& prim) {
    LightDesc light = *prim.light;
    light.type = LightType::Mesh;
    light.name = prim.path;
    light.mesh = prim.mesh;
    light.doubleSided = prim.doubleSided;
    if (light.tintByMaterial && prim.material >= 0) {
      const MaterialDesc& m = desc_.materials[size_t(prim.material)];
      if (!m.emissionTexture.enabled() && !isBlack(m.emission)) light.color = light.color * m.emission;
    }
    light.tintByMaterial = false;
    std::vector<Transform> xfs = prim.instances.empty() ? std::vector<Transform>(1) : prim.instances;
    for (const Transform& xf : xfs) {
      light.xf = xf;
      validateUsdLight(light, prim.path);
      desc_.lights.push_back(light);
    }
  }

  const std::vector<MeshPrim>& prims_;
  SceneDesc& desc_;
  const PrimLookup& lookup_;
  std::map<std::string, size_t> byPath_;
  std::map<std::string, std::optional<MeshPrim>> lookedUp_;
  std::map<std::string, int> grainMaterials_;
  std::set<std::string> prototypes_;
};

}  // namespace

bool isAggregatePrimvar(const std::string& name) {
  return std::any_of(std::begin(kAggregatePrimvars), std::end(kAggregatePrimvars),
                     [&](const char* n) { return name == n; });
}

bool isGrainPrimvar(const std::string& name) {
  return std::any_of(std::begin(kGrainPrimvars), std::end(kGrainPrimvars), [&](const char* n) { return name == n; });
}

std::string resolvePrototypePath(const std::string& aggregatePath, const std::string& text) {
  const std::string attr = usdName("prototypes");
  if (text.empty()) throw InputError(aggregatePath, attr, "has an empty path");
  ParsedPath p;
  try {
    p = PathParser(text).parse();
  } catch (const PathSyntaxError& e) {
    throw InputError(aggregatePath, attr, str("\"", text, "\" is not a valid path (", e.why, ")"));
  }
  const std::string notPrim = str("\"", text, "\" is not a prim path");
  if (!p.primPath) throw InputError(aggregatePath, attr, notPrim);
  if (p.absolute) return text;
  std::vector<std::string> base = splitPrimPath(aggregatePath);
  // Climbing above the root leaves no path at all (SdfPath: the empty path).
  if (p.up > int(base.size())) throw InputError(aggregatePath, attr, notPrim);
  base.resize(base.size() - size_t(p.up));
  std::string out;
  for (const std::string& e : base) out += "/" + e;
  if (!p.elements.empty()) out += "/" + p.elements;
  if (out.empty()) throw InputError(aggregatePath, attr, notPrim);  // the root is no prim
  return out;
}

AggregateValues readAggregateValues(const MeshPrim& prim) {
  AggregateValues v;
  if (const PrimvarValue* x = typed(prim, "grainRadius", Kind::Float)) v.grainRadius = float(x->numbers[0]);
  if (const PrimvarValue* x = typed(prim, "packingRate", Kind::Float)) v.packingRate = float(x->numbers[0]);
  if (const PrimvarValue* x = typed(prim, "prototypes", Kind::StringArray)) v.prototypes = x->strings;
  if (const PrimvarValue* x = typed(prim, "weights", Kind::FloatArray))
    v.weights.assign(x->numbers.begin(), x->numbers.end());
  if (const PrimvarValue* x = typed(prim, "seed", Kind::Int)) v.seed = toInt64(x->numbers[0]);
  if (const PrimvarValue* x = typed(prim, "tileSpheres", Kind::Int)) v.tileSpheres = toInt64(x->numbers[0]);
  if (const PrimvarValue* x = typed(prim, "sizes", Kind::FloatArray)) v.sizes.assign(x->numbers.begin(), x->numbers.end());
  if (const PrimvarValue* x = typed(prim, "sizeSpread", Kind::Float)) v.sizeSpread = float(x->numbers[0]);
  return v;
}

GrainValues readGrainValues(const MeshPrim& prim) {
  GrainValues v;
  if (const PrimvarValue* x = typed(prim, "ior", Kind::Float)) v.ior = float(x->numbers[0]);
  if (const PrimvarValue* x = typed(prim, "absorption", Kind::Color3))
    v.absorption = Vec3(float(x->numbers[0]), float(x->numbers[1]), float(x->numbers[2]));
  if (const PrimvarValue* x = typed(prim, "roughness", Kind::Float)) v.roughness = float(x->numbers[0]);
  return v;
}

void assembleGranularScene(const std::vector<MeshPrim>& prims, SceneDesc& desc, const PrimLookup& lookup) {
  Assembler(prims, desc, lookup).run();
}

namespace {

struct HalfNumbers {
  const uint16_t* p;
  float operator[](size_t i) const { return imath_half_to_float(p[i]); }
};
template <class T>
struct Numbers {
  const T* p;
  T operator[](size_t i) const { return p[i]; }
};

// fn(numbers) with the view's numbers typed (operator[]: float for floats, the integer type
// for integers).
template <class Fn>
void withNumbers(const NumberView& v, Fn&& fn) {
  switch (v.type) {
    case NumberView::Type::Half: return fn(HalfNumbers{static_cast<const uint16_t*>(v.data)});
    case NumberView::Type::Float: return fn(Numbers<float>{static_cast<const float*>(v.data)});
    case NumberView::Type::Double: return fn(Numbers<double>{static_cast<const double*>(v.data)});
    case NumberView::Type::Int32: return fn(Numbers<int32_t>{static_cast<const int32_t*>(v.data)});
    case NumberView::Type::Int64: return fn(Numbers<int64_t>{static_cast<const int64_t*>(v.data)});
  }
}

template <class T>
NumberView viewOf(const std::vector<T>& v, NumberView::Type type) {
  return NumberView{v.data(), v.size(), type};
}


}  // namespace

InstancedGrainsDesc instancedGrainsFromUsd(const InstancerPrim& prim, SceneDesc& desc, const PrimLookup& lookup) {
  InstancerArrays a;
  a.read = [&prim](const std::string& attr) {
    if (attr == "protoIndices") return viewOf(prim.protoIndices, NumberView::Type::Int64);
    const std::vector<float>& v = attr == "positions"      ? prim.positions
                                  : attr == "orientations" ? prim.orientations
                                  : attr == "scales"       ? prim.scales
                                  : attr == "velocities"   ? prim.velocities
                                                           : prim.angularVelocities;
    return viewOf(v, NumberView::Type::Float);
  };
  return instancedGrainsFromUsd(prim, a, desc, lookup);
}

InstancedGrainsDesc instancedGrainsFromUsd(const InstancerPrim& prim, const InstancerArrays& arrays, SceneDesc& desc,
                                           const PrimLookup& lookup) {
  const std::string& path = prim.path;
  if (prim.typeName != "PointInstancer")
    throw InputError(path, "", str(kInstancedAggregateApi, " applies to a PointInstancer, not a ",
                                   prim.typeName.empty() ? "typeless prim" : prim.typeName));
  InstancedGrainsDesc g;
  g.name = path;
  g.xf = prim.xf;
  g.id = prim.id;
  g.linkCategories = prim.linkCategories;
  auto per = [&](const char* attr, const NumberView& v, size_t k) {
    if (v.count % k) throw InputError(path, attr, str("has ", v.count, " numbers, not ", k, " per instance"));
    return v.count / k;
  };
  auto vectors = [&](const char* attr, const NumberView& v) {
    std::vector<Vec3> out(per(attr, v, 3));
    Vec3* o = out.data();
    withNumbers(v, [&](auto x) {
      tbb::parallel_for(tbb::blocked_range<size_t>(0, out.size(), 16384), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i < r.end(); ++i) o[i] = Vec3(float(x[3 * i]), float(x[3 * i + 1]), float(x[3 * i + 2]));
      });
    });
    return out;
  };
  g.positions = vectors("positions", arrays.read("positions"));
  g.velocities = vectors("velocities", arrays.read("velocities"));
  g.angularVelocities = vectors("angularVelocities", arrays.read("angularVelocities"));
  {
    // (w, x, y, z) from the array's order.
    const int w = arrays.orientationsRealLast ? 3 : 0, v0 = arrays.orientationsRealLast ? 0 : 1;
    const NumberView view = arrays.read("orientations");
    std::vector<Quat> q(per("orientations", view, 4));
    int64_t bad = -1;
    withNumbers(view, [&](auto x) {
      bad = firstBadInstance(q.size(), [&](size_t i) {
        const float c[4] = {float(x[4 * i + w]), float(x[4 * i + v0]), float(x[4 * i + v0 + 1]), float(x[4 * i + v0 + 2])};
        const float n = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2] + c[3] * c[3]);
        if (!(n > 0) || !std::isfinite(n)) return true;
        q[i] = Quat{c[0] / n, c[1] / n, c[2] / n, c[3] / n};
        return false;
      });
      if (bad >= 0) {
        const size_t i = size_t(bad);
        throw InputError(path, "orientations",
                         str("instance ", i, " has (", float(x[4 * i + w]), ", ", float(x[4 * i + v0]), ", ",
                             float(x[4 * i + v0 + 1]), ", ", float(x[4 * i + v0 + 2]), "), not a rotation"));
      }
    });
    g.orientations = std::move(q);
  }
  {
    const NumberView view = arrays.read("scales");
    std::vector<float> scales(per("scales", view, 3));
    withNumbers(view, [&](auto x) {
      // 0: fine; 1: not positive or not finite; 2: not uniform.
      auto check = [&](size_t i, float& kept) {
        const float s[3] = {float(x[3 * i]), float(x[3 * i + 1]), float(x[3 * i + 2])};
        const float lo = std::min({s[0], s[1], s[2]}), hi = std::max({s[0], s[1], s[2]});
        kept = hi;
        if (!(lo > 0) || !std::isfinite(hi)) return 1;
        // A grain is one size: an ellipsoidal grain would need its own prototype.
        return hi - lo > 1e-3f * hi ? 2 : 0;
      };
      const int64_t bad = firstBadInstance(scales.size(), [&](size_t i) { return check(i, scales[i]) != 0; });
      if (bad < 0) return;
      const size_t i = size_t(bad);
      float kept;
      const int why = check(i, kept);
      const std::string shown = str("(", float(x[3 * i]), ", ", float(x[3 * i + 1]), ", ", float(x[3 * i + 2]), ")");
      if (why == 1)
        throw InputError(path, "scales", str("instance ", i, " has scale ", shown, " (each must be > 0 and finite)"));
      throw InputError(path, "scales", str("instance ", i, " has non-uniform scale ", shown,
                                           ": a grain takes one size (scale its prototype instead)"));
    });
    g.scales = std::move(scales);
  }
  const int64_t protos = int64_t(prim.prototypes.size());
  {
    const NumberView view = arrays.read("protoIndices");
    std::vector<int32_t> indices(view.count);
    withNumbers(view, [&](auto x) {
      // Floats (a front end's choice, not USD's int[]) truncated toward zero; -1 when no integer.
      auto index = [&](size_t i) {
        const auto v = x[i];
        if constexpr (std::is_floating_point_v<decltype(v)>)
          return std::isfinite(v) && std::fabs(v) < 9.2e18 ? int64_t(v) : int64_t(-1);
        else
          return int64_t(v);
      };
      const int64_t bad = firstBadInstance(indices.size(), [&](size_t i) {
        const int64_t k = index(i);
        if (k < 0 || k >= protos) return true;
        indices[i] = int32_t(k);
        return false;
      });
      if (bad >= 0)
        throw InputError(path, "protoIndices", str("instance ", bad, " has ", index(size_t(bad)),
                                                   ", not the index of one of its ", protos, " prototypes"));
    });
    g.protoIndices = std::move(indices);
  }
  if (!prim.prototypeXforms.empty() && prim.prototypeXforms.size() != prim.prototypes.size())
    throw InputError(path, "prototypes", str(prim.prototypeXforms.size(), " transforms for ", protos, " prototypes"));
  std::map<std::string, int> materials;
  for (size_t k = 0; k < prim.prototypes.size(); ++k) {
    const std::string& target = prim.prototypes[k];
    const std::string what = str("target ", target);
    MeshPrim proto;
    if (!lookup || !lookup(target, proto)) throw InputError(path, "prototypes", what + " is not a prim of the stage");
    if (!proto.active) throw InputError(path, "prototypes", what + " is inactive");
    if (proto.typeName != "Mesh")
      throw InputError(path, "prototypes",
                       str(what, " is a ", proto.typeName.empty() ? "typeless prim" : proto.typeName,
                           ", not a Mesh (a grain prototype is one closed mesh)"));
    const bool aggregate = proto.apiSchemas ? hasApi(proto, kAggregateApi) : proto.granular.count("prototypes") > 0;
    if (aggregate)
      throw InputError(path, "prototypes",
                       str(what, " is itself an aggregate (", kAggregateApi, "): a grain prototype is a plain mesh"));
    GrainPrototypeDesc p;
    p.name = proto.path;
    p.mesh = prim.prototypeXforms.empty() ? proto.mesh : proto.mesh.transformed(prim.prototypeXforms[k]);
    validateClosed(p.mesh, proto.path);
    auto it = materials.find(proto.path);
    p.material = it != materials.end() ? it->second : appendGrainMaterial(proto, desc);
    materials.emplace(proto.path, p.material);
    g.prototypes.push_back(std::move(p));
  }
  validateInstancedGrains(g);
  return g;
}

bool isExplicitGrainInstancer(const std::optional<std::vector<std::string>>& instancerApiSchemas,
                              const std::vector<MeshPrim>& prototypes) {
  if (instancerApiSchemas && std::find(instancerApiSchemas->begin(), instancerApiSchemas->end(),
                                       kInstancedAggregateApi) != instancerApiSchemas->end())
    return true;
  return !prototypes.empty() && std::all_of(prototypes.begin(), prototypes.end(), [](const MeshPrim& p) {
    return p.apiSchemas ? hasApi(p, kGrainApi) : anyGrainPrimvar(p);
  });
}

InstancedGrainsDesc instancedGrainsFromPrototypeInstances(InstancerPrim prim,
                                                          const std::vector<std::vector<int64_t>>& instancesOf,
                                                          const std::vector<int64_t>& authoredProtoIndices,
                                                          SceneDesc& desc, const PrimLookup& lookup) {
  // As many instances as any array or list implies: a list or protoIndices longer than
  // positions is then reported by instancedGrainsFromUsd as the lengths' mismatch.
  size_t n = std::max(prim.positions.size() / 3, authoredProtoIndices.size());
  for (const std::vector<int64_t>& list : instancesOf)
    for (int64_t i : list) {
      if (i < 0) throw InputError(prim.path, "protoIndices", str("the host lists instance ", i, " (not an index)"));
      n = std::max(n, size_t(i) + 1);
    }
  std::vector<int64_t> owner(n, -1);
  for (size_t k = 0; k < instancesOf.size(); ++k)
    for (int64_t i : instancesOf[k]) {
      if (owner[size_t(i)] >= 0)
        throw InputError(prim.path, "protoIndices", str("instance ", i, " is drawn with prototypes ", owner[size_t(i)],
                                                        " and ", k, " (one each)"));
      owner[size_t(i)] = int64_t(k);
    }
  const int64_t protos = int64_t(prim.prototypes.size());
  std::vector<uint8_t> drawn(n, 1);
  prim.protoIndices.assign(n, 0);
  for (size_t i = 0; i < n; ++i) {
    if (owner[i] >= 0) {
      prim.protoIndices[i] = owner[i];
      continue;
    }
    const bool authored = i < authoredProtoIndices.size();
    if (authored && (authoredProtoIndices[i] < 0 || authoredProtoIndices[i] >= protos)) {
      prim.protoIndices[i] = authoredProtoIndices[i];  // reported below, as granular render reports it
      continue;
    }
    drawn[i] = 0;  // masked: checked as the first prototype's, then left out
  }
  InstancedGrainsDesc g = instancedGrainsFromUsd(prim, desc, lookup);
  if (std::find(drawn.begin(), drawn.end(), 0) != drawn.end()) keepInstances(g, drawn);
  return g;
}

void keepInstances(InstancedGrainsDesc& g, const std::vector<uint8_t>& keep) {
  auto compact = [&](auto& values) {
    if (values.size() != keep.size()) return;  // unauthored
    auto& v = values.vec();
    size_t out = 0;
    for (size_t i = 0; i < keep.size(); ++i)
      if (keep[i]) v[out++] = v[i];
    v.resize(out);
  };
  compact(g.positions);
  compact(g.orientations);
  compact(g.scales);
  compact(g.protoIndices);
  compact(g.velocities);
  compact(g.angularVelocities);
}

}  // namespace granular
