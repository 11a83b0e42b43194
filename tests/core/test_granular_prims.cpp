// test_granular_prims.cpp — the granular schema's meaning on plain prims: which are
// aggregates, prototypes and ordinary meshes, materials, fallbacks, instancing, and every
// error with its exact message in USD terms.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <ostream>
#include <string>

#include "core/error.h"
#include "core/granular_prims.h"
#include "test_helpers.h"
#include "core/shapes.h"

using namespace granular;
using granular::testing::errorOf;

namespace {

PrimvarValue number(const std::string& type, double v) {
  PrimvarValue p;
  p.typeName = type;
  p.numbers = {v};
  return p;
}

PrimvarValue numbers(const std::string& type, std::vector<double> v, bool array = true) {
  PrimvarValue p;
  p.typeName = type;
  p.numbers = std::move(v);
  p.isArray = array;
  return p;
}

PrimvarValue strings(std::vector<std::string> v, const std::string& type = "string[]") {
  PrimvarValue p;
  p.typeName = type;
  p.strings = std::move(v);
  p.isArray = true;
  p.isString = true;
  return p;
}

MeshPrim meshPrim(const std::string& path, TriangleMesh mesh, std::vector<std::string> apis = {}) {
  MeshPrim p;
  p.path = path;
  p.mesh = std::move(mesh);
  p.apiSchemas = std::move(apis);
  return p;
}

// The stage tests/python/conftest.py's small_scene describes, as a front end lists it:
// /World/Castle (an aggregate of a relative and an absolute prototype), /World/Grains/A
// (GranularGrainAPI), /World/Grains/B (a bound material, front-end index 0), and an
// ordinary /World/Ground. desc holds that one front-end material.
struct Stage {
  std::vector<MeshPrim> prims;
  SceneDesc desc;

  Stage() {
    MaterialDesc slate;
    slate.name = "/World/Looks/Slate";
    slate.albedo = Vec3(0.3f);
    desc.materials.push_back(slate);

    MeshPrim a = meshPrim("/World/Grains/A", makeIcosphere(1), {kGrainApi});
    a.visible = false;
    a.granular["ior"] = number("float", 1.31);
    a.granular["absorption"] = numbers("color3f", {0.2, 0.3, 0.5}, false);
    a.granular["roughness"] = number("float", 0);
    a.id = 11;
    MeshPrim b = meshPrim("/World/Grains/B", makeRock(1, 0.2f, 3));
    b.visible = false;
    b.material = 0;
    b.id = 12;
    MeshPrim castle = meshPrim("/World/Castle", makeBox(Vec3(-0.2f, 0, -0.2f), Vec3(0.2f, 0.3f, 0.2f)), {kAggregateApi});
    castle.granular["grainRadius"] = number("float", 0.03);
    castle.granular["packingRate"] = number("float", 0.5);
    castle.granular["prototypes"] = strings({"../Grains/A", "/World/Grains/B"});
    castle.granular["weights"] = numbers("float[]", {0.7, 0.3});
    castle.granular["seed"] = number("int", 3);
    castle.granular["tileSpheres"] = number("int", 64);
    castle.instances = {Transform::translate(Vec3(1, 2, 3))};
    castle.id = 7;
    MeshPrim ground = meshPrim("/World/Ground", makeBox(Vec3(-1, -0.1f, -1), Vec3(1, 0, 1)));
    ground.material = 0;
    ground.id = 8;
    prims = {a, b, castle, ground};
  }

  MeshPrim& operator[](const std::string& path) {
    for (MeshPrim& p : prims)
      if (p.path == path) return p;
    throw std::logic_error("no prim " + path);
  }

  void assemble(const PrimLookup& lookup = {}) { assembleGranularScene(prims, desc, lookup); }
};

// assembleGranularScene throws exactly `message`.
void expectError(Stage& s, const std::string& message, const PrimLookup& lookup = {}) {
  try {
    s.assemble(lookup);
  } catch (const InputError& e) {
    EXPECT_EQ(e.what(), message);
    return;
  }
  ADD_FAILURE() << "no InputError; expected: " << message;
}

const std::string P = "primvars:granular:";

}  // namespace

TEST(GranularPrims, AssemblesTheAggregateFromItsPrototypesAndDrawsTheRest) {
  Stage s;
  s.assemble();
  ASSERT_EQ(s.desc.aggregates.size(), 1u);
  const AggregateDesc& a = s.desc.aggregates[0];
  EXPECT_EQ(a.name, "/World/Castle");
  EXPECT_EQ(a.id, 7);
  EXPECT_FLOAT_EQ(a.grainRadius, 0.03f);
  EXPECT_FLOAT_EQ(a.packingRate, 0.5f);
  EXPECT_EQ(a.seed, 3u);
  EXPECT_EQ(a.tileSpheres, 64);
  EXPECT_EQ(a.weights, (std::vector<float>{0.7f, 0.3f}));
  EXPECT_DOUBLE_EQ(a.xf.m[1][3], 2.0);
  EXPECT_EQ(a.boundary.numTriangles(), 12u);
  // A relative and an absolute entry, in their order.
  ASSERT_EQ(a.prototypes.size(), 2u);
  EXPECT_EQ(a.prototypes[0].name, "/World/Grains/A");
  EXPECT_EQ(a.prototypes[1].name, "/World/Grains/B");
  EXPECT_EQ(a.prototypes[1].mesh.points.size(), s["/World/Grains/B"].mesh.points.size());
  // Neither the prototypes nor the boundary are ordinary geometry.
  ASSERT_EQ(s.desc.meshes.size(), 1u);
  EXPECT_EQ(s.desc.meshes[0].name, "/World/Ground");
  EXPECT_EQ(s.desc.meshes[0].material, 0);
  EXPECT_EQ(s.desc.meshes[0].id, 8);
  // The result is a scene core accepts as it is.
  EXPECT_NO_THROW(validateSceneDesc(s.desc));
}

TEST(GranularPrims, GrainMaterialsComeFromGrainValuesThenTheFrontEndThenClearGlass) {
  Stage s;
  // C: no grain values, no material: clear glass (-1). D: grain primvars without the
  // API still make a grain material. B also has a display colour, which grains ignore.
  s.prims.push_back(meshPrim("/World/Grains/C", makeIcosphere(0)));
  MeshPrim d = meshPrim("/World/Grains/D", makeIcosphere(0));
  d.granular["ior"] = number("double", 1.7);
  d.granular["roughness"] = number("float", 0.3);
  d.material = 0;
  s.prims.push_back(d);
  s["/World/Grains/B"].displayColor = Vec3(1, 0, 0);
  s["/World/Castle"].granular["prototypes"] = strings({"../Grains/A", "../Grains/B", "../Grains/C", "../Grains/D"});
  s["/World/Castle"].granular.erase("weights");
  s.assemble();
  const AggregateDesc& a = s.desc.aggregates.at(0);
  ASSERT_EQ(a.prototypes.size(), 4u);
  const MaterialDesc& ma = s.desc.materials.at(size_t(a.prototypes[0].material));
  EXPECT_EQ(ma.type, MaterialType::Dielectric);
  EXPECT_EQ(ma.name, "/World/Grains/A");
  EXPECT_FLOAT_EQ(ma.ior, 1.31f);
  EXPECT_FLOAT_EQ(ma.absorption.z, 0.5f);
  EXPECT_EQ(a.prototypes[1].material, 0);
  EXPECT_EQ(a.prototypes[2].material, -1);
  const MaterialDesc& md = s.desc.materials.at(size_t(a.prototypes[3].material));
  EXPECT_EQ(md.type, MaterialType::Dielectric);
  EXPECT_FLOAT_EQ(md.ior, 1.7f);
  EXPECT_FLOAT_EQ(md.roughness, 0.3f);  // rough grains (GGX α = 0.09)
  EXPECT_EQ(ma.roughness, 0.0f);
  EXPECT_EQ(a.weights, (std::vector<float>{1, 1, 1, 1}));  // [] = equal
  EXPECT_EQ(s.desc.materials.size(), 3u);                 // slate, A, D: B's colour made none
}

TEST(GranularPrims, APrototypeSharedByAggregatesGetsOneMaterial) {
  Stage s;
  MeshPrim second = s["/World/Castle"];
  second.path = "/World/Castle2";
  s.prims.push_back(second);
  s.assemble();
  ASSERT_EQ(s.desc.aggregates.size(), 2u);
  EXPECT_EQ(s.desc.aggregates[0].prototypes[0].material, s.desc.aggregates[1].prototypes[0].material);
  EXPECT_EQ(s.desc.materials.size(), 2u);
}

TEST(GranularPrims, UnauthoredValuesTakeTheSchemaFallbacks) {
  Stage s;
  MeshPrim& c = s["/World/Castle"];
  c.granular = {{"prototypes", strings({"../Grains/A"})}};
  s["/World/Grains/A"].granular.clear();  // the API alone: a grain of the fallbacks
  s.assemble();
  const AggregateDesc& a = s.desc.aggregates.at(0);
  EXPECT_FLOAT_EQ(a.grainRadius, 0.01f);
  EXPECT_FLOAT_EQ(a.packingRate, 0.6f);
  EXPECT_EQ(a.seed, 1u);
  EXPECT_EQ(a.tileSpheres, 512);
  EXPECT_EQ(a.weights, (std::vector<float>{1.0f}));
  const MaterialDesc& m = s.desc.materials.at(size_t(a.prototypes[0].material));
  EXPECT_EQ(m.type, MaterialType::Dielectric);
  EXPECT_FLOAT_EQ(m.ior, 1.5f);
  EXPECT_EQ(m.absorption.x, 0.0f);

  AggregateValues v = readAggregateValues(meshPrim("/X", {}));
  EXPECT_TRUE(v.prototypes.empty() && v.weights.empty());
  GrainValues g = readGrainValues(meshPrim("/X", {}));
  EXPECT_FLOAT_EQ(g.ior, 1.5f);
  EXPECT_EQ(g.roughness, 0.0f);
}

TEST(GranularPrims, WiderTypesStandForTheSchemaTypes) {
  MeshPrim p = meshPrim("/X", {});
  p.granular["packingRate"] = number("double", 0.25);
  p.granular["seed"] = number("int64", 9);
  p.granular["tileSpheres"] = number("uint", 128);
  p.granular["weights"] = numbers("double[]", {2, 1});
  p.granular["ior"] = number("half", 1.25);
  p.granular["absorption"] = numbers("color3d", {1, 2, 3}, false);
  AggregateValues v = readAggregateValues(p);
  EXPECT_FLOAT_EQ(v.packingRate, 0.25f);
  EXPECT_EQ(v.seed, 9);
  EXPECT_EQ(v.tileSpheres, 128);
  EXPECT_EQ(v.weights, (std::vector<float>{2, 1}));
  GrainValues g = readGrainValues(p);
  EXPECT_FLOAT_EQ(g.ior, 1.25f);
  EXPECT_FLOAT_EQ(g.absorption.y, 2.0f);
}

TEST(GranularPrims, OneAggregateAndOneMeshPerInstanceTransform) {
  Stage s;
  s["/World/Castle"].instances = {Transform::translate(Vec3(0, 0, 0)), Transform::translate(Vec3(5, 0, 0)),
                                  Transform::scale(Vec3(2))};
  s["/World/Ground"].instances = {Transform(), Transform::translate(Vec3(0, -1, 0))};
  s.assemble();
  ASSERT_EQ(s.desc.aggregates.size(), 3u);
  EXPECT_DOUBLE_EQ(s.desc.aggregates[1].xf.m[0][3], 5.0);
  EXPECT_DOUBLE_EQ(s.desc.aggregates[2].xf.m[0][0], 2.0);
  for (const AggregateDesc& a : s.desc.aggregates) {
    EXPECT_EQ(a.id, 7);
    EXPECT_EQ(a.prototypes.size(), 2u);
  }
  // One grain material for all instances.
  EXPECT_EQ(s.desc.aggregates[0].prototypes[0].material, s.desc.aggregates[2].prototypes[0].material);
  ASSERT_EQ(s.desc.meshes.size(), 2u);
  EXPECT_DOUBLE_EQ(s.desc.meshes[1].xf.m[1][3], -1.0);
  EXPECT_EQ(s.desc.meshes[1].id, 8);
  // No instances: the identity.
  Stage t;
  t["/World/Castle"].instances.clear();
  t.assemble();
  EXPECT_DOUBLE_EQ(t.desc.aggregates.at(0).xf.m[0][3], 0.0);
  EXPECT_DOUBLE_EQ(t.desc.aggregates.at(0).xf.m[0][0], 1.0);
}

TEST(GranularPrims, EachInstanceIsInThePrimsLightLinkCategoriesAndItsOwn) {
  Stage s;
  s["/World/Castle"].instances = {Transform(), Transform::translate(Vec3(5, 0, 0))};
  s["/World/Castle"].linkCategories = {"rim"};
  s["/World/Castle"].instanceLinkCategories = {{}, {"key", "fill"}};
  s["/World/Ground"].linkCategories = {"key"};
  s.assemble();
  ASSERT_EQ(s.desc.aggregates.size(), 2u);
  EXPECT_EQ(s.desc.aggregates[0].linkCategories, std::vector<std::string>{"rim"});
  EXPECT_EQ(s.desc.aggregates[1].linkCategories, (std::vector<std::string>{"rim", "key", "fill"}));
  EXPECT_EQ(s.desc.meshes.at(0).linkCategories, std::vector<std::string>{"key"});
  Stage t;
  t["/World/Ground"].instanceLinkCategories = {{"key"}, {"fill"}};  // one instance
  EXPECT_EQ(errorOf([&] { t.assemble(); }), "/World/Ground.instanceCategories: 2 category lists for 1 instances");
}

TEST(GranularPrims, VisibilityAndTheGrainApiDecideWhatIsDrawn) {
  Stage s;
  s["/World/Grains/B"].visible = true;  // a visible prototype is still not drawn
  MeshPrim spare = meshPrim("/World/Spare", makeIcosphere(0), {kGrainApi});  // named by no one
  s.prims.push_back(spare);
  MeshPrim hidden = meshPrim("/World/Hidden", makeIcosphere(0));
  hidden.visible = false;
  s.prims.push_back(hidden);
  MeshPrim hiddenAggregate = s["/World/Castle"];
  hiddenAggregate.path = "/World/HiddenCastle";
  hiddenAggregate.visible = false;
  hiddenAggregate.granular["packingRate"] = number("float", 0.9);  // never read: not an aggregate
  s.prims.push_back(hiddenAggregate);
  // Known API schemas decide: inherited aggregate primvars do not make an aggregate.
  MeshPrim rock = meshPrim("/World/Rock", makeIcosphere(0));
  rock.granular["grainRadius"] = number("float", 0.05);
  rock.granular["grainRadius"].source = "/World";
  s.prims.push_back(rock);
  MeshPrim cube = meshPrim("/World/Cube", makeBox(Vec3(0), Vec3(1)));
  cube.typeName = "Cube";
  s.prims.push_back(cube);
  s.assemble();
  EXPECT_EQ(s.desc.aggregates.size(), 1u);
  std::vector<std::string> drawn;
  for (const MeshDesc& m : s.desc.meshes) drawn.push_back(m.name);
  EXPECT_EQ(drawn, (std::vector<std::string>{"/World/Ground", "/World/Rock", "/World/Cube"}));
}

TEST(GranularPrims, WithoutApiSchemasThePrimvarsDecide) {
  // A Hydra delegate sees primvars only, inherited ones flattened onto every mesh.
  Stage s;
  for (MeshPrim& p : s.prims) p.apiSchemas.reset();
  PrimvarValue inherited = number("float", 0.5);
  inherited.source = "/World";
  for (MeshPrim& p : s.prims) p.granular["packingRate"] = inherited;
  s["/World/Ground"].granular.clear();
  s["/World/Grains/B"].visible = true;
  MeshPrim grain = meshPrim("/World/Grain", makeIcosphere(0));  // grain primvars: not drawn
  grain.granular["ior"] = number("float", 1.4);
  grain.apiSchemas.reset();
  s.prims.push_back(grain);
  s.assemble();
  // B inherits packingRate but is named as a prototype; A carries grain primvars.
  ASSERT_EQ(s.desc.aggregates.size(), 1u);
  EXPECT_EQ(s.desc.aggregates[0].name, "/World/Castle");
  ASSERT_EQ(s.desc.meshes.size(), 1u);
  EXPECT_EQ(s.desc.meshes[0].name, "/World/Ground");
}

TEST(GranularPrims, DisplayColourMakesALambertForMeshesWithoutMaterial) {
  Stage s;
  MeshPrim& g = s["/World/Ground"];
  g.material = -1;
  g.displayColor = Vec3(0.8f, 0.1f, 0.1f);
  s.assemble();
  const MeshDesc& m = s.desc.meshes.at(0);
  ASSERT_GE(m.material, 0);
  const MaterialDesc& md = s.desc.materials[size_t(m.material)];
  EXPECT_EQ(md.name, "/World/Ground.displayColor");
  EXPECT_EQ(md.type, MaterialType::Lambert);
  EXPECT_FLOAT_EQ(md.albedo.x, 0.8f);
}

TEST(GranularPrims, PrototypesNotListedAreLookedUpOnce) {
  Stage s;
  MeshPrim b = s["/World/Grains/B"];
  s.prims.erase(s.prims.begin() + 1);  // B is not listed (invisible, say)
  MeshPrim second = s["/World/Castle"];
  second.path = "/World/Castle2";
  s.prims.push_back(second);
  int calls = 0;
  s.assemble([&](const std::string& path, MeshPrim& out) {
    ++calls;
    if (path != b.path) return false;
    out = b;
    return true;
  });
  EXPECT_EQ(calls, 1);
  ASSERT_EQ(s.desc.aggregates.size(), 2u);
  EXPECT_EQ(s.desc.aggregates[1].prototypes[1].name, "/World/Grains/B");
  EXPECT_EQ(s.desc.aggregates[1].prototypes[1].material, 0);
  EXPECT_EQ(s.desc.meshes.size(), 1u);  // a looked-up prim is never drawn
}

TEST(GranularPrims, PrototypePathsResolveLikeSdfPaths) {
  EXPECT_EQ(resolvePrototypePath("/World/Castle", "../Grains/Round"), "/World/Grains/Round");
  EXPECT_EQ(resolvePrototypePath("/World/Castle", "/Lib/Grains/Round"), "/Lib/Grains/Round");
  EXPECT_EQ(resolvePrototypePath("/World/Castle", "Grains/Round"), "/World/Castle/Grains/Round");
  EXPECT_EQ(resolvePrototypePath("/World/Castle", "."), "/World/Castle");
  EXPECT_EQ(resolvePrototypePath("/World/Castle", ".."), "/World");
  EXPECT_EQ(resolvePrototypePath("/Shot/A/Castle", "../../B/Grains/R"), "/Shot/B/Grains/R");
  EXPECT_EQ(resolvePrototypePath("/W", "../Wörld"), "/Wörld");
  EXPECT_EQ(resolvePrototypePath("/W", "/A{v=x}B"), "/A{v=x}B");
  const std::string where = "/W/C.primvars:granular:prototypes: ";
  auto error = [](const std::string& text) {
    try {
      resolvePrototypePath("/W/C", text);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("(no error)");
  };
  EXPECT_EQ(error(""), where + "has an empty path");
  EXPECT_EQ(error("a b"), where + "\"a b\" is not a valid path (Ill-formed SdfPath <a b> at character 2 (' '): "
                                  "expected end of path)");
  EXPECT_EQ(error("/A/"), where + "\"/A/\" is not a valid path (Ill-formed SdfPath </A/> at character 4: "
                                  "expected prim name)");
  EXPECT_EQ(error("//A"), where + "\"//A\" is not a valid path (Ill-formed SdfPath <//A> at character 2 ('/'): "
                                  "expected end of path)");
  EXPECT_EQ(error("A/../B"), where + "\"A/../B\" is not a valid path (Ill-formed SdfPath <A/../B> at character 3 "
                                     "('.'): expected prim name)");
  EXPECT_EQ(error("1A"), where + "\"1A\" is not a valid path (Ill-formed SdfPath <1A> at character 1 ('1'): "
                                 "expected a path beginning with '/', '.', or a prim name)");
  EXPECT_EQ(error("./A"), where + "\"./A\" is not a valid path (Ill-formed SdfPath <./A> at character 2 ('/'): "
                                  "expected property name after '.')");
  EXPECT_EQ(error("/A.b.c"), where + "\"/A.b.c\" is not a valid path (Ill-formed SdfPath </A.b.c> at character 6 "
                                     "('c'): expected 'mapper' or 'expression' after '.')");
  EXPECT_EQ(error("/A{v}"), where + "\"/A{v}\" is not a valid path (Ill-formed SdfPath </A{v}> at character 5 "
                                    "('}'): expected '=' after variant set name)");
  EXPECT_EQ(error("/A.b::c"), where + "\"/A.b::c\" is not a valid path (Ill-formed SdfPath </A.b::c> at character "
                                      "6 (':'): expected identifier after ':')");
  for (const char* notPrim : {"/", "/A.b", "/A.b:c", "/A{v=x}", "/A{v=x}{w=y}", "/A.b[/C]", "/A.b[/C].d", "../..", "../../../X", "A.b"})
    EXPECT_EQ(error(notPrim), where + "\"" + notPrim + "\" is not a prim path") << notPrim;
}

TEST(GranularPrims, SchemaPropertyNames) {
  for (const char* n : {"grainRadius", "packingRate", "prototypes", "weights", "seed", "tileSpheres"}) {
    EXPECT_TRUE(isAggregatePrimvar(n)) << n;
    EXPECT_FALSE(isGrainPrimvar(n)) << n;
  }
  for (const char* n : {"ior", "absorption", "roughness"}) {
    EXPECT_TRUE(isGrainPrimvar(n)) << n;
    EXPECT_FALSE(isAggregatePrimvar(n)) << n;
  }
  EXPECT_FALSE(isAggregatePrimvar("primvars:granular:seed"));
  EXPECT_FALSE(isGrainPrimvar("displayColor"));
}

// ---- every error, exactly ------------------------------------------------------------------

struct ErrorCase {
  const char* name;
  std::function<void(Stage&)> mutate;
  std::string message;
};

// ctest lists a case by its name, not by its bytes.
void PrintTo(const ErrorCase& c, std::ostream* os) { *os << c.name; }

class GranularPrimsError : public ::testing::TestWithParam<ErrorCase> {};

TEST_P(GranularPrimsError, NamesThePrimAndTheAttribute) {
  Stage s;
  GetParam().mutate(s);
  expectError(s, GetParam().message);
}

namespace {

std::function<void(Stage&)> set(const std::string& path, const std::string& name, PrimvarValue v) {
  return [=](Stage& s) { s[path].granular[name] = v; };
}

const std::string C = "/World/Castle." + P;
const std::string A = "/World/Grains/A." + P;

}  // namespace

INSTANTIATE_TEST_SUITE_P(
    AllCases, GranularPrimsError,
    ::testing::Values(
        ErrorCase{"packingRate", set("/World/Castle", "packingRate", number("float", 0.9)),
                  C + "packingRate: 0.9 is outside (0, 0.64]"},
        ErrorCase{"zeroPackingRate", set("/World/Castle", "packingRate", number("float", 0)),
                  C + "packingRate: 0 is outside (0, 0.64]"},
        ErrorCase{"inheritedPackingRate",
                  [](Stage& s) {
                    PrimvarValue v = number("float", 0.7);
                    v.source = "/World";
                    s["/World/Castle"].granular["packingRate"] = v;
                  },
                  "/World.primvars:granular:packingRate: 0.7 is outside (0, 0.64]"},
        ErrorCase{"grainRadius", set("/World/Castle", "grainRadius", number("float", -0.5)),
                  C + "grainRadius: -0.5 must be finite and > 0"},
        ErrorCase{"nanGrainRadius", set("/World/Castle", "grainRadius", number("float", NAN)),
                  C + "grainRadius: nan must be finite and > 0"},
        ErrorCase{"tileSpheres", set("/World/Castle", "tileSpheres", number("int", 4)),
                  C + "tileSpheres: 4 is outside [8, 100000]"},
        ErrorCase{"manyTileSpheres", set("/World/Castle", "tileSpheres", number("int64", 200000)),
                  C + "tileSpheres: 200000 is outside [8, 100000]"},
        ErrorCase{"seed", set("/World/Castle", "seed", number("int", -3)), C + "seed: -3 must be >= 0"},
        ErrorCase{"missingPrototype", set("/World/Castle", "prototypes", strings({"../Grains/A", "../Grains/Nope"})),
                  C + "prototypes: prototype \"../Grains/Nope\" (/World/Grains/Nope) does not exist"},
        ErrorCase{"selfAsPrototype", set("/World/Castle", "prototypes", strings({"../Grains/A", "/World/Castle"})),
                  C + "prototypes: prototype \"/World/Castle\" (/World/Castle) is this aggregate itself"},
        ErrorCase{"selfAsPrototypeWithoutApiSchemas",
                  [](Stage& s) {
                    for (MeshPrim& p : s.prims) p.apiSchemas.reset();
                    s["/World/Castle"].granular["prototypes"] = strings({"."});
                  },
                  C + "prototypes: prototype \".\" (/World/Castle) is this aggregate itself"},
        ErrorCase{"aggregateAsPrototype",
                  [](Stage& s) {
                    MeshPrim other = s["/World/Castle"];
                    other.path = "/World/Tower";
                    s.prims.push_back(other);
                    s["/World/Castle"].granular["prototypes"] = strings({"../Tower"});
                  },
                  C + "prototypes: prototype \"../Tower\" (/World/Tower) is itself an aggregate (GranularAggregateAPI): "
                      "a grain prototype is a plain mesh"},
        ErrorCase{"aggregatesNamingEachOtherWithoutApiSchemas",
                  [](Stage& s) {
                    for (MeshPrim& p : s.prims) p.apiSchemas.reset();
                    MeshPrim other = s["/World/Castle"];
                    other.path = "/World/Tower";
                    other.granular["prototypes"] = strings({"../Castle"});
                    s.prims.push_back(other);
                    s["/World/Castle"].granular["prototypes"] = strings({"../Tower"});
                  },
                  C + "prototypes: prototype \"../Tower\" (/World/Tower) is itself an aggregate (GranularAggregateAPI): "
                      "a grain prototype is a plain mesh"},
        ErrorCase{"inactivePrototype", [](Stage& s) { s["/World/Grains/B"].active = false; },
                  C + "prototypes: prototype \"/World/Grains/B\" (/World/Grains/B) is inactive"},
        ErrorCase{"nonMeshPrototype", [](Stage& s) { s["/World/Grains/B"].typeName = "Sphere"; },
                  C + "prototypes: prototype \"/World/Grains/B\" (/World/Grains/B) is a Sphere, not a Mesh"},
        ErrorCase{"typelessPrototype", [](Stage& s) { s["/World/Grains/B"].typeName = ""; },
                  C + "prototypes: prototype \"/World/Grains/B\" (/World/Grains/B) is a typeless prim, not a Mesh"},
        ErrorCase{"inheritedPrototypes",
                  [](Stage& s) {
                    PrimvarValue v = strings({"Nope"});
                    v.source = "/World";
                    s["/World/Castle"].granular["prototypes"] = v;
                  },
                  "/World.primvars:granular:prototypes: prototype \"Nope\" (/World/Castle/Nope) does not exist"},
        ErrorCase{"invalidPrototypePath", set("/World/Castle", "prototypes", strings({"a b"})),
                  C + "prototypes: \"a b\" is not a valid path (Ill-formed SdfPath <a b> at character 2 (' '): "
                      "expected end of path)"},
        ErrorCase{"propertyPrototypePath", set("/World/Castle", "prototypes", strings({"../Grains/A.points"})),
                  C + "prototypes: \"../Grains/A.points\" is not a prim path"},
        ErrorCase{"emptyPrototypePath", set("/World/Castle", "prototypes", strings({""})),
                  C + "prototypes: has an empty path"},
        ErrorCase{"noPrototypes", set("/World/Castle", "prototypes", strings({})),
                  C + "prototypes: is empty (at least one grain prototype mesh is needed)"},
        ErrorCase{"unauthoredPrototypes", [](Stage& s) { s["/World/Castle"].granular.erase("prototypes"); },
                  C + "prototypes: is empty (at least one grain prototype mesh is needed)"},
        ErrorCase{"weightsCount", set("/World/Castle", "weights", numbers("float[]", {1, 2, 3})),
                  C + "weights: has 3 entries but there are 2 prototypes"},
        ErrorCase{"negativeWeight", set("/World/Castle", "weights", numbers("float[]", {1, -1})),
                  C + "weights: weight 1 = -1 must be finite and >= 0"},
        ErrorCase{"zeroWeights", set("/World/Castle", "weights", numbers("float[]", {0, 0})),
                  C + "weights: are all zero"},
        ErrorCase{"grainIor", set("/World/Grains/A", "ior", number("float", 5)), A + "ior: 5 is outside [1, 4]"},
        ErrorCase{"inheritedGrainIor",
                  [](Stage& s) {
                    PrimvarValue v = number("float", 0.5);
                    v.source = "/World/Grains";
                    s["/World/Grains/A"].granular["ior"] = v;
                  },
                  "/World/Grains.primvars:granular:ior: 0.5 is outside [1, 4]"},
        ErrorCase{"grainAbsorption", set("/World/Grains/A", "absorption", numbers("color3f", {-1, 0, 0}, false)),
                  A + "absorption: (-1, 0, 0) has a negative component"},
        ErrorCase{"grainRoughnessRange", set("/World/Grains/A", "roughness", number("float", 2)),
                  A + "roughness: 2 is outside [0, 1]"},
        ErrorCase{"negativeRoughness", set("/World/Grains/A", "roughness", number("float", -0.1f)),
                  A + "roughness: -0.1 is outside [0, 1]"},
        ErrorCase{"roughnessWithoutApi",
                  [](Stage& s) { s["/World/Grains/B"].granular["roughness"] = number("float", 1.5); },
                  "/World/Grains/B." + P + "roughness: 1.5 is outside [0, 1]"},
        ErrorCase{"stringRadius",
                  set("/World/Castle", "grainRadius", [] {
                    PrimvarValue v;
                    v.typeName = "string";
                    v.isString = true;
                    v.strings = {"big"};
                    return v;
                  }()),
                  C + "grainRadius: has type string, expected float"},
        ErrorCase{"floatSeed", set("/World/Castle", "seed", number("float", 7)), C + "seed: has type float, expected int"},
        ErrorCase{"boolSeed", set("/World/Castle", "seed", number("bool", 1)), C + "seed: has type bool, expected int"},
        ErrorCase{"scalarPrototypes",
                  set("/World/Castle", "prototypes",
                      [] {
                        PrimvarValue v = strings({"../Grains/A"}, "string");
                        v.isArray = false;
                        return v;
                      }()),
                  C + "prototypes: has type string, expected string[]"},
        ErrorCase{"tokenPrototypes", set("/World/Castle", "prototypes", strings({"../Grains/A"}, "token[]")),
                  C + "prototypes: has type token[], expected string[]"},
        ErrorCase{"stringWeights", set("/World/Castle", "weights", strings({"1", "2"})),
                  C + "weights: has type string[], expected float[]"},
        ErrorCase{"floatAbsorption", set("/World/Grains/A", "absorption", number("float", 1)),
                  A + "absorption: has type float, expected color3f"},
        ErrorCase{"vertexInterpolation",
                  [](Stage& s) { s["/World/Castle"].granular["packingRate"].interpolation = "vertex"; },
                  C + "packingRate: has interpolation vertex, expected constant"},
        ErrorCase{"twoNumbersForAFloat", set("/World/Castle", "grainRadius", numbers("float", {1, 2}, false)),
                  C + "grainRadius: has value (1, 2), expected a float"},
        ErrorCase{"fractionalInt", set("/World/Castle", "seed", number("int", 1.5)),
                  C + "seed: has value 1.5, expected a int"},
        ErrorCase{"shortColour", set("/World/Grains/A", "absorption", numbers("color3f", {1, 2}, false)),
                  A + "absorption: has value (1, 2), expected a color3f"},
        ErrorCase{"apiOnAnXform",
                  [](Stage& s) {
                    MeshPrim x = meshPrim("/World/Thing", {}, {kAggregateApi});
                    x.typeName = "Xform";
                    s.prims.push_back(x);
                  },
                  "/World/Thing: GranularAggregateAPI applies to a Mesh, not a Xform"},
        ErrorCase{"apiOnATypelessPrim",
                  [](Stage& s) {
                    MeshPrim x = meshPrim("/World/Thing", {}, {kAggregateApi});
                    x.typeName = "";
                    s.prims.push_back(x);
                  },
                  "/World/Thing: GranularAggregateAPI applies to a Mesh, not a typeless prim"},
        ErrorCase{"openBoundary",
                  [](Stage& s) {
                    TriangleMesh& m = s["/World/Castle"].mesh;
                    m.indices.resize(m.indices.size() - 3);
                  },
                  "/World/Castle.faceVertexIndices: open boundary: edge (4,6) is used by 1 triangle(s)"},
        ErrorCase{"nanPrototypePoint",
                  [](Stage& s) { s["/World/Grains/B"].mesh.points[0] = Vec3(NAN, 0, 0); },
                  "/World/Grains/B.points: point 0 is not finite (nan, 0, 0)"},
        ErrorCase{"singularInstance",
                  [](Stage& s) { s["/World/Castle"].instances = {Transform(), Transform::scale(Vec3(1, 0, 1))}; },
                  "/World/Castle.transform: is singular (not invertible)"}),
    [](const ::testing::TestParamInfo<ErrorCase>& info) { return std::string(info.param.name); });

// ---- explicit grains as a Hydra front end sees them -------------------------------------------

namespace {

// /World/Sim's prototype /World/Sim/Protos/<name>: a closed icosphere with a grain primvar
// (Hydra: no API schemas known) or none.
PrimLookup hydraPrototypes(bool grainPrimvar = true) {
  return [=](const std::string& path, MeshPrim& out) {
    if (path.rfind("/World/Sim/Protos/", 0) != 0) return false;
    out.path = path;
    out.mesh = makeIcosphere(1);
    if (grainPrimvar) out.granular["ior"] = number("float", 1.31);
    return true;
  };
}

// Five instances 3 apart along x, two prototypes.
InstancerPrim hydraInstancer() {
  InstancerPrim p;
  p.path = "/World/Sim";
  p.prototypes = {"/World/Sim/Protos/A", "/World/Sim/Protos/B"};
  for (int i = 0; i < 5; ++i) p.positions.insert(p.positions.end(), {3.0f * float(i), 0, 0});
  for (int i = 0; i < 5; ++i) p.scales.insert(p.scales.end(), {1.0f + 0.1f * float(i), 1.0f + 0.1f * float(i), 1.0f + 0.1f * float(i)});
  return p;
}


}  // namespace

TEST(GranularPrims, AnInstancerIsOfExplicitGrainsByItsApiOrItsPrototypes) {
  MeshPrim grain = meshPrim("/G", makeIcosphere(1), {kGrainApi}), plain = meshPrim("/P", makeIcosphere(1));
  const std::vector<std::string> api = {kInstancedAggregateApi}, none = {};
  // usd-core sees API schemas: the instancer's API, or GranularGrainAPI on every prototype.
  EXPECT_TRUE(isExplicitGrainInstancer(api, {plain}));
  EXPECT_TRUE(isExplicitGrainInstancer(none, {grain, grain}));
  EXPECT_FALSE(isExplicitGrainInstancer(none, {grain, plain}));
  EXPECT_FALSE(isExplicitGrainInstancer(none, {}));
  // Hydra sees none: a grain primvar on every prototype decides (authored, or inherited from
  // the instancer); the API alone is invisible there.
  MeshPrim hydraGrain = meshPrim("/G", makeIcosphere(1)), hydraPlain = meshPrim("/P", makeIcosphere(1));
  hydraGrain.apiSchemas.reset();
  hydraPlain.apiSchemas.reset();
  hydraGrain.granular["absorption"] = numbers("color3f", {1, 1, 1}, false);
  hydraPlain.granular["grainRadius"] = number("float", 0.1);  // an aggregate's primvar: no grain
  EXPECT_TRUE(isExplicitGrainInstancer(std::nullopt, {hydraGrain, hydraGrain}));
  EXPECT_FALSE(isExplicitGrainInstancer(std::nullopt, {hydraGrain, hydraPlain}));
  EXPECT_FALSE(isExplicitGrainInstancer(std::nullopt, {}));
}

// Hydra lists each prototype's instances, not protoIndices: they are rebuilt from the lists,
// masked instances (in no list) left out after the checks, and the result is
// instancedGrainsFromUsd's on the same instancer with those protoIndices.
TEST(GranularPrims, InstancedGrainsFromEachPrototypesInstances) {
  SceneDesc viaLists, viaIndices;
  InstancedGrainsDesc g =
      instancedGrainsFromPrototypeInstances(hydraInstancer(), {{0, 3}, {1, 2, 4}}, {}, viaLists, hydraPrototypes());
  InstancerPrim authored = hydraInstancer();
  authored.protoIndices = {0, 1, 1, 0, 1};
  InstancedGrainsDesc expected = instancedGrainsFromUsd(authored, viaIndices, hydraPrototypes());
  EXPECT_EQ(g.protoIndices, expected.protoIndices);
  ASSERT_EQ(g.size(), 5u);
  for (size_t i = 0; i < 5; ++i) {
    EXPECT_EQ(g.positions[i], expected.positions[i]);
    EXPECT_EQ(g.scales[i], expected.scales[i]);
  }
  EXPECT_EQ(viaLists.materials.size(), 2u);  // each prototype's grain primvars

  // Instances 1 and 3 masked (USD's invisibleIds): left out, the rest in order.
  SceneDesc masked;
  g = instancedGrainsFromPrototypeInstances(hydraInstancer(), {{0}, {2, 4}}, {}, masked, hydraPrototypes());
  EXPECT_EQ(g.protoIndices, (std::vector<int32_t>{0, 1, 1}));
  ASSERT_EQ(g.size(), 3u);
  EXPECT_EQ(g.positions[1], Vec3(6, 0, 0));
  EXPECT_EQ(g.positions[2], Vec3(12, 0, 0));
  EXPECT_FLOAT_EQ(g.scales[2], 1.4f);
  // The authored protoIndices, where seen, tell a mask from an index naming no prototype.
  SceneDesc seen;
  g = instancedGrainsFromPrototypeInstances(hydraInstancer(), {{0}, {2, 4}}, {0, 1, 1, 0, 1}, seen, hydraPrototypes());
  EXPECT_EQ(g.size(), 3u);
}

TEST(GranularPrims, InstancedGrainsFromEachPrototypesInstancesNameTheAttribute) {
  auto read = [](InstancerPrim p, std::vector<std::vector<int64_t>> lists, std::vector<int64_t> authored = {}) {
    return errorOf([&] {
      SceneDesc s;
      instancedGrainsFromPrototypeInstances(p, lists, authored, s, hydraPrototypes());
    });
  };
  // An authored index naming no prototype (Hydra drew that instance with none).
  EXPECT_EQ(read(hydraInstancer(), {{0, 3}, {1, 4}}, {0, 1, 7, 0, 1}),
            "/World/Sim.protoIndices: instance 2 has 7, not the index of one of its 2 prototypes");
  // Checks name instances by their authored index, masked ones included.
  InstancerPrim p = hydraInstancer();
  p.positions[3 * 3] = NAN;
  EXPECT_EQ(read(p, {{0}, {1, 2, 4}}), "/World/Sim.positions: instance 3 is at (nan, 0, 0) (not finite)");
  p = hydraInstancer();
  p.positions.resize(4 * 3);  // the host lists an instance beyond the positions
  EXPECT_EQ(read(p, {{0, 3}, {1, 2, 4}}), "/World/Sim.positions: has 4 values but protoIndices has 5 (one per instance)");
  EXPECT_EQ(read(hydraInstancer(), {{0, 3}, {1, 3}}),
            "/World/Sim.protoIndices: instance 3 is drawn with prototypes 0 and 1 (one each)");
  p = hydraInstancer();
  p.scales[4] = 2;
  EXPECT_EQ(read(p, {{0, 3}, {1, 2, 4}}).rfind("/World/Sim.scales: instance 1 has non-uniform scale", 0), 0u);
}

TEST(GranularPrims, ASurfaceWithALightIsAMeshLightPerInstanceNotDrawn) {
  SceneDesc desc;
  MaterialDesc glow;
  glow.name = "glow";
  glow.emission = Vec3(1.0f, 0.5f, 0.25f);
  desc.materials.push_back(glow);
  MeshPrim panel = meshPrim("/World/Panel", makeBox(Vec3(0.0f), Vec3(1.0f)));
  panel.instances = {Transform::translate(Vec3(0, 2, 0)), Transform::translate(Vec3(3, 2, 0))};
  panel.material = 0;
  panel.doubleSided = true;
  LightDesc light;
  light.type = LightType::Mesh;
  light.color = Vec3(0.5f);
  light.tintByMaterial = true;
  panel.light = light;
  MeshPrim untinted = meshPrim("/World/Untinted", makeBox(Vec3(0.0f), Vec3(1.0f)));
  untinted.material = 0;
  untinted.light = light;
  untinted.light->tintByMaterial = false;
  MeshPrim hidden = untinted;
  hidden.path = "/World/Hidden";
  hidden.visible = false;  // an invisible light emits nothing
  assembleGranularScene({panel, untinted, hidden, meshPrim("/World/Ground", makeBox(Vec3(-1.0f), Vec3(1.0f)))}, desc);
  ASSERT_EQ(desc.meshes.size(), 1u);  // the ground alone is drawn
  EXPECT_EQ(desc.meshes[0].name, "/World/Ground");
  ASSERT_EQ(desc.lights.size(), 3u);
  for (int i : {0, 1}) {
    const LightDesc& l = desc.lights[size_t(i)];
    EXPECT_EQ(l.name, "/World/Panel");
    EXPECT_EQ(l.type, LightType::Mesh);
    EXPECT_EQ(l.mesh.numTriangles(), 12u);
    EXPECT_TRUE(l.doubleSided);
    EXPECT_FALSE(l.tintByMaterial);  // applied
    EXPECT_EQ(l.color, Vec3(0.5f, 0.25f, 0.125f));
  }
  EXPECT_EQ(desc.lights[0].xf.point(Vec3(0.0f)), Vec3(0, 2, 0));
  EXPECT_EQ(desc.lights[1].xf.point(Vec3(0.0f)), Vec3(3, 2, 0));
  EXPECT_EQ(desc.lights[2].name, "/World/Untinted");
  EXPECT_EQ(desc.lights[2].color, Vec3(0.5f));
  EXPECT_FALSE(desc.lights[2].doubleSided);
  // A light core refuses names the prim, in USD's names.
  SceneDesc bad;
  MeshPrim flat = meshPrim("/World/Flat", makeBox(Vec3(0.0f), Vec3(1.0f)));
  flat.light = light;
  flat.light->intensity = -1;
  EXPECT_EQ(granular::testing::errorOf([&] { assembleGranularScene({flat}, bad); }),
            "/World/Flat.inputs:intensity: -1 must be finite and >= 0");
}
