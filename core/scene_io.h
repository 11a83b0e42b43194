// scene_io.h — the JSON scene format: parse a file or a string into a SceneDesc.
//
// Contract: parseSceneJson() fills a SceneDesc and runs validateSceneDesc() on it.
// Every problem (syntax, wrong type, unknown or duplicate key, unknown material,
// value out of range, open boundary mesh...) throws InputError whose message names
// the object and the JSON key, e.g. `castle.packing_rate: 0.9 is outside (0, 0.64]`.
// No nlohmann exception ever escapes. Relative file paths ("obj", "texture_file") are
// resolved against the folder of sourceName (the current directory if it has none).
//
// Format (// comments allowed; every key optional unless marked *):
// {
//  "render": {"width":640, "height":480, "spp":16, "seed":0, "max_depth":65536, "rr_depth":8, "threads":0,
//             "motion_blur":true},   // false: the shutter's instant (no blur, meshes still)
//  "camera": {"look_at": {"eye":[0,1,5], "target":[0,0,0], "up":[0,1,0]},  // or "transform": T
//             "focal_length":50, "horizontal_aperture":36, "vertical_aperture":24,
//             "horizontal_aperture_offset":0, "vertical_aperture_offset":0, "clipping_range":[0.01,1000],
//             "shutter_open":0, "shutter_close":0},  // seconds about the frame: motion blur
//  "materials": {"sand":  {"type":"dielectric", "ior":1.5, "absorption":[0.1,0.2,0.4],
//                         "roughness":0, "energy_compensation":true},
//                "floor": {"type":"lambert", "albedo":[0.5,0.5,0.5], "emission":0}},
//  "meshes": [{"name":"floor", "shape"*: S, "material":"floor", "transform": T, "visible":true,
//              "shutter_transforms": [T_open, T_close]}],  // moves linearly over the shutter
//  "lights": [{"type"*:"distant", "direction":[0,-1,-1], "angle":0.53},   // or "transform": T
//             {"type"*:"sphere", "position":[0,3,0], "radius":0.5},         // or "transform": T
//             {"type"*:"rect", "transform":T, "width":1, "height":1},
//             {"type"*:"disk", "transform":T, "radius":0.5},                // emits along its -Z
//             {"type"*:"cylinder", "transform":T, "radius":0.5, "length":1}, // along its X, from its side
//             {"type"*:"mesh", "shape"*: S, "transform":T, "double_sided":false}, // from its front faces
//             {"type"*:"dome", "texture_file":"sky.exr", "transform":T}],
//             // every light also takes "name", "color":[1,1,1], "intensity":1, "exposure":0,
//             // "normalize":false, "light_link": {"include": [names], "exclude": [names]}
//             // (light linking: the meshes, aggregates and instanced grains it lights,
//             // every one unless "include" lists them, less "exclude"; LightDesc::lightLink);
//             // radiance = color * intensity * 2^exposure; the area
//             // lights but a mesh also "shaping_cone_angle":90, "shaping_cone_softness":0,
//             // "shaping_focus":0, "shaping_focus_tint":[0,0,0], "shaping_ies_file":"spot.ies"
//             // (an IES LM-63 profile, relative to the scene file), "shaping_ies_angle_scale":0,
//             // "shaping_ies_normalize":false (UsdLuxShapingAPI; any of them turns shaping on)
//  "aggregates": [{"name":"castle", "boundary"*: S, "transform": T, "grain_radius":0.01,
//                  "packing_rate":0.6, "seed":1, "tile_spheres":512,
//                  "prototypes"*: [{"name":"rock", "shape"*: S, "material":"sand"}],
//                  "weights":[1],  // default: all 1
//                  "shutter_transforms": [T_open, T_close]}],  // moves over the shutter, as a mesh
//  "instanced_grains": [{"name":"pile", "transform": T,     // a simulation's grains (PointInstancer)
//                  "prototypes"*: [{"name":"rock", "shape"*: S, "material":"sand"}],
//                  "positions"*: [[x,y,z], ...], "proto_indices"*: [0, ...],  // one per grain
//                  "orientations": [[w,x,y,z], ...], "scales": [s, ...],      // unit; > 0
//                  "velocities": [[x,y,z], ...],           // units per second
//                  "angular_velocities": [[x,y,z], ...]}]  // degrees per second
// }
// Transform T: [16 numbers] row-major, acting on column vectors (like Transform), or
//   {"matrix":[16 numbers]}, or {"translate":[x,y,z], "rotate":[deg,ax,ay,az],
//   "scale":[x,y,z] or s}, applied as translate * rotate * scale.
// Shape S: an object with exactly one of
//   {"box": {"lo":[-1,-1,-1], "hi":[1,1,1]}}          {"icosphere": {"subdivisions":2, "radius":1}}
//   {"uvsphere": {"segments":32, "rings":16, "radius":1}}
//   {"lathe": {"profile"*: [[r,h], ...bottom to top], "segments":64}}
//   {"rock": {"subdivisions":3, "roughness":0.2, "seed":0}}
//   {"ellipsoid": {"radii"*: [rx,ry,rz], "subdivisions":3}}
//   {"mesh": {"points"*: [[x,y,z], ...] or [x,y,z, ...], "face_vertex_indices"*: [...],
//             "face_vertex_counts": [...]}}   // counts default to all triangles
//   {"obj": "path.obj"}                        // Wavefront OBJ, v and f lines only
// Names default to "meshes[i]", "lights[i]", "aggregates[i]", "instanced_grains[i]"; a
// prototype is named "<aggregate>/<name>" (or "<aggregate>.prototypes[j]"). Materials are referenced by
// name; a mesh without one is grey Lambert, a prototype without one clear glass.
#pragma once

#include <string>

#include "mesh.h"
#include "scene_desc.h"

namespace granular {

// Reads the file and parses it; relative paths inside resolve against its folder.
SceneDesc loadSceneJson(const std::string& path);

// Parses JSON text; sourceName is used in error messages and to resolve relative paths.
SceneDesc parseSceneJson(const std::string& text, const std::string& sourceName);

// Minimal Wavefront OBJ reader: `v` and `f` lines (f entries may be v, v/vt, v//vn,
// v/vt/vn; negative indices count back from the latest vertex); polygons are
// fan-triangulated; everything else is ignored. Errors name `object`.
TriangleMesh loadObj(const std::string& path, const std::string& object);

}  // namespace granular
