// usd_lights.h — UsdLux lights on plain records (usd_values.h): which types render, the
// attributes read with UsdLux's fallbacks, and what is refused or warned about. Both USD
// front ends hand a light prim's record here, so a light means the same in `granular
// render` and in hdGranular.
//
// Types (UsdPrimRecord::typeName, USD's schema names; Hydra's sprim types capitalised):
//  - DistantLight: inputs:angle (degrees, 0.53);
//  - DomeLight, DomeLight_1: inputs:texture:file (a lat-long image; must exist),
//    inputs:texture:format (automatic or latlong; others refused);
//  - RectLight: inputs:width, inputs:height (1); a texture is warned about and ignored;
//  - SphereLight: inputs:radius (0.5); treatAsPoint is warned about (a sphere is drawn);
//  - DiskLight: inputs:radius (0.5);
//  - CylinderLight: inputs:radius (0.5), inputs:length (1); treatAsLine is warned about;
//  - ShapingAPI on the area lights above: inputs:shaping:cone:angle (90),
//    inputs:shaping:cone:softness (0), inputs:shaping:focus (0), inputs:shaping:focusTint
//    (0, 0, 0), inputs:shaping:ies:file (an IES LM-63 profile, ies.h; must exist and parse),
//    inputs:shaping:ies:angleScale (0), inputs:shaping:ies:normalize (false) (LightShaping,
//    scene_desc.h), on where any of them has a value; on a distant or dome light it is
//    warned about and ignored;
//  - ShadowAPI: inputs:shadow:enable (true; false: no object casts shadows from the light,
//    LightDesc::shadows); inputs:shadow:color, :distance, :falloff and :falloffGamma off
//    their fallbacks (0, -1, -1, 1) are warned about and ignored;
//  - inputs:diffuse and inputs:specular other than 1 (non-physical controls): one warning
//    each, ignored;
//  - a surface with MeshLightAPI (Mesh, an implicit surface): a mesh light (LightType::Mesh)
//    whose triangles the front end's MeshPrim gives (granular_prims.h): the surface is the
//    light's body, emitting from its front faces (both sides when doubleSided) and
//    reflecting nothing, whatever its light:materialSyncMode; materialGlowTintsLight (the
//    fallback) multiplies inputs:color by the bound material's emissiveColor where that is
//    a colour other than black (a textured one does not tint); ShapingAPI on it is warned
//    about and ignored;
//  - any other light type (PortalLight, a GeometryLight, ...): one warning, skipped.
// Light linking: a front end gives collection:lightLink and collection:shadowLink (tokens)
// when the light's collection of that name does not hold every prim (includeRoot with no
// exclude): the collection's name, which each drawn prim it includes lists in its
// linkCategories (granular_prims.h; Hydra's categories, usd-core's membership query). The
// light then lights those objects alone (LightDesc::lightLink), and only the objects its
// shadowLink includes cast shadows from it (LightDesc::shadowLink).
// Every light: inputs:intensity (1), inputs:exposure (0), inputs:color (1, 1, 1),
// inputs:normalize (false), and inputs:colorTemperature (6500 K, > 0) when
// inputs:enableColorTemperature is true: the colour is multiplied by blackbodyRgb of it.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "scene_desc.h"
#include "usd_values.h"

namespace granular {

// The attributes lightFromUsd reads, by USD name; a front end reads these (and may read
// more: unknown ones are ignored).
const std::vector<std::string>& usdLightAttributeNames();
// The record's entries for light linking (above): not attributes, what the front end's
// collection machinery names the light's collections.
inline constexpr const char* kUsdLightLink = "collection:lightLink";
inline constexpr const char* kUsdShadowLink = "collection:shadowLink";

// The LightDesc of a light prim's record (name = path, xf = record.xf), or nothing for a
// type that is not rendered (a warning says so). InputError naming prim.attribute on a
// value of the wrong type or out of range.
std::optional<LightDesc> lightFromUsd(const UsdPrimRecord& light, UsdWarnings& warnings);

// validateLightDesc (geometry as there) with errors in USD's names: inputs:intensity, a
// ShapingAPI input, transform, points.
void validateUsdLight(const LightDesc& l, const std::string& path, bool geometry = true);

// The lights in the order both front ends sample them: by prim path, element by element
// (SdfPath's dictionary order), so that a seed draws the same light for a sample whatever
// order the stage or the host lists them in.
void orderUsdLights(std::vector<LightDesc>& lights);

// The colour of a blackbody at `kelvin` in linear Rec.709 with luminance 1 (Planck's law
// integrated against the CIE 1931 2° observer, in the analytic fit of Wyman, Sloan and
// Shirley 2013, "Simple Analytic Approximations to the CIE XYZ Color Matching
// Functions"); like UsdLux, temperatures are clamped to [1000, 10000] K and negative
// components to 0.
Vec3 blackbodyRgb(float kelvin);

}  // namespace granular
