// usd_camera.h — UsdGeomCamera on a plain record (usd_values.h), for both USD front ends.
//
// Attributes and UsdGeomCamera's fallbacks: projection (perspective; orthographic is
// refused), focalLength (50), horizontalAperture (20.955), verticalAperture (15.2908),
// horizontalApertureOffset and verticalApertureOffset (0), all in tenths of a scene unit;
// clippingRange ((1, 1000000)); fStop (0: a pinhole; else lensRadiusFromFStop) and
// focusDistance (must be > 0 with a lens); shutter:open and shutter:close (0, 0: no motion
// blur; in time codes relative to the frame, made seconds by the stage's
// timeCodesPerSecond). Every check names prim.attribute.
#pragma once

#include <string>
#include <vector>

#include "scene_desc.h"
#include "usd_values.h"

namespace granular {

const std::vector<std::string>& usdCameraAttributeNames();

// The camera (cameraToWorld = record.xf).
CameraDesc cameraFromUsd(const UsdPrimRecord& camera, double timeCodesPerSecond = 24.0);

}  // namespace granular
