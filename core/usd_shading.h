// usd_shading.h — a bound material's UsdShade network on plain records (usd_values.h):
// the UsdPreviewSurface rule and UsdUVTexture networks, for both USD front ends.
//
// The rule (UsdPreviewSurface's inputs and fallbacks: diffuseColor (0.18, 0.18, 0.18),
// emissiveColor (0, 0, 0), opacity 1, opacityThreshold 0, ior 1.5):
//  - opacity < 1 with no threshold and no opacity texture is glass: a Dielectric of ior;
//    diffuse and emissive textures on it are ignored (a warning);
//  - anything else is Lambert of diffuseColor emitting emissiveColor; an opacity < 1, a
//    textured opacity or a threshold > 0 makes it a cut-out (MaterialDesc::opacity);
//  - diffuseColor, emissiveColor and opacity may be connected to a UsdUVTexture's output
//    (rgb, r, g, b, a; opacity reads r of rgb, with a warning): its inputs:file (must
//    exist; UDIM refused), wrapS / wrapT, scale, bias and sourceColorSpace with
//    UsdUVTexture's fallbacks, and its st from a UsdPrimvarReader_float2's varname (a
//    UsdTransform2d in between is warned about and skipped);
//  - other connections and shader types are warned about, and the input's own value, or
//    the default material, is used.
// Errors name the shader prim and its input, e.g. /Looks/Sand/Surface.inputs:opacity.
#pragma once

#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "scene_desc.h"
#include "usd_mesh.h"
#include "usd_values.h"

namespace granular {

// A shader of a material network: its prim path (UsdPrimRecord::path), info:id
// (typeName, e.g. "UsdPreviewSurface"), its authored inputs by full name
// ("inputs:diffuseColor") and, per connected input, the shader and output feeding it.
struct UsdShaderRecord : UsdPrimRecord {
  std::map<std::string, std::pair<std::string, std::string>> connections;  // "inputs:st" -> (path, "result")
};

// A material as bound: its path, the shader its surface output reads (empty: none), and
// every shader upstream of that one (any order).
struct UsdMaterialNetwork {
  std::string material;
  std::string surface;
  std::vector<UsdShaderRecord> shaders;
};

// A network's material and the primvar its textures read as st ("" when none does).
struct UsdMaterial {
  MaterialDesc desc;
  std::string st;
};

// The material of a network, or nothing when it has no supported surface (a warning says
// so): meshes bound to it then use the default material, not their displayColor.
std::optional<UsdMaterial> materialFromUsd(const UsdMaterialNetwork& network, UsdWarnings& warnings);

// A mesh's primvars:displayColor (any interpolation), averaged: a mesh with no bound
// material is Lambert of it (granular_prims.h). Nothing when it holds no value, or when
// its count does not fit its interpolation on `mesh` (given for a Mesh; a warning says
// so: Hydra hosts drop such a primvar). InputError on
// <value.source or prim>.primvars:displayColor when its numbers are not colours, or their
// mean is outside [0, 1].
std::optional<Vec3> displayColorFromUsd(const UsdValue& value, const UsdMeshRecord* mesh, const std::string& prim,
                                        UsdWarnings& warnings);

}  // namespace granular
