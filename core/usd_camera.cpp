// usd_camera.cpp — UsdGeomCamera on a plain record (usd_camera.h).
#include "usd_camera.h"

#include <cmath>

#include "error.h"

namespace granular {

const std::vector<std::string>& usdCameraAttributeNames() {
  static const std::vector<std::string> names = {
      "projection",      "focalLength",      "horizontalAperture", "verticalAperture", "horizontalApertureOffset",
      "verticalApertureOffset", "clippingRange", "fStop",          "focusDistance", "shutter:open",
      "shutter:close"};
  return names;
}

CameraDesc cameraFromUsd(const UsdPrimRecord& r, double timeCodesPerSecond) {
  const std::string& path = r.path;
  if (usdToken(r, "projection", "perspective") != "perspective")
    throw InputError(path, "projection", "orthographic cameras are not supported (use perspective)");
  CameraDesc c;
  c.cameraToWorld = r.xf;
  c.focalLength = usdFloat(r, "focalLength", 50.0f);
  c.horizontalAperture = usdFloat(r, "horizontalAperture", 20.955f);
  c.verticalAperture = usdFloat(r, "verticalAperture", 15.2908f);
  c.horizontalApertureOffset = usdFloat(r, "horizontalApertureOffset", 0.0f);
  c.verticalApertureOffset = usdFloat(r, "verticalApertureOffset", 0.0f);
  const std::vector<float> clip = usdFloats(r, "clippingRange", {1.0f, 1000000.0f});
  c.clipNear = clip[0];
  c.clipFar = clip[1];
  c.lensRadius = checkedLensRadius(c.focalLength, usdFloat(r, "fStop", 0.0f), path, "fStop");
  c.focusDistance = usdFloat(r, "focusDistance", 0.0f);
  if (c.lensRadius > 0 && !(std::isfinite(c.focusDistance) && c.focusDistance > 0))
    throw InputError(path, "focusDistance", str(c.focusDistance, " must be > 0 when fStop is set"));
  if (!(timeCodesPerSecond > 0) || !std::isfinite(timeCodesPerSecond))
    throw InputError(path, "shutter:open", str("the stage's timeCodesPerSecond ", timeCodesPerSecond, " must be > 0"));
  const double open = usdFloat(r, "shutter:open", 0.0f), close = usdFloat(r, "shutter:close", 0.0f);
  if (!std::isfinite(open)) throw InputError(path, "shutter:open", str(open, " is not finite"));
  if (!std::isfinite(close)) throw InputError(path, "shutter:close", str(close, " is not finite"));
  if (close < open) throw InputError(path, "shutter:close", str(close, " is before shutter:open ", open));
  c.shutterOpen = float(open / timeCodesPerSecond);
  c.shutterClose = float(close / timeCodesPerSecond);
  // Core's checks of a camera, in USD's names (its fields are the attributes, the lens is fStop).
  checkInUsdNames(path, [&] { validateCameraDesc(c, path); },
                  [](const std::string& field) {
                    return field == "lensRadius"     ? std::string("fStop")
                           : field == "shutterOpen"  ? std::string("shutter:open")
                           : field == "shutterClose" ? std::string("shutter:close")
                                                     : field;
                  });
  return c;
}

}  // namespace granular
