#include "camera.h"

#include "error.h"

namespace granular {

Camera::Camera(const CameraDesc& desc, int width, int height)
    : toWorld_(desc.cameraToWorld), width_(width), height_(height), clipNear_(desc.clipNear), clipFar_(desc.clipFar) {
  if (!toWorld_.inverse(toCamera_)) throw InputError("camera", "transform", "is singular");
  position_ = toWorld_.point(Vec3(0.0f));
  float apAspect = desc.horizontalAperture / desc.verticalAperture;
  float imAspect = float(width) / float(height);
  float hAp = desc.horizontalAperture, vAp = desc.verticalAperture;
  if (imAspect > apAspect) hAp = vAp * imAspect; else vAp = hAp / imAspect;
  halfW_ = 0.5f * hAp / desc.focalLength;
  halfH_ = 0.5f * vAp / desc.focalLength;
  offX_ = desc.horizontalApertureOffset / desc.focalLength;
  offY_ = desc.verticalApertureOffset / desc.focalLength;
}

Ray Camera::generateRay(float px, float py) const {
  float sx = 2.0f * px / width_ - 1.0f;
  float sy = 1.0f - 2.0f * py / height_;
  Vec3 dCam(sx * halfW_ + offX_, sy * halfH_ + offY_, -1.0f);
  float invLen = 1.0f / length(dCam);
  Ray r;
  r.o = position_;
  r.d = normalize(toWorld_.vector(dCam));
  // The clip range is along the view axis; along this ray it scales by |dCam|.
  r.tmin = clipNear_ / invLen;
  r.tmax = clipFar_ / invLen;
  return r;
}

float Camera::viewDepth(const Vec3& p) const { return -toCamera_.point(p).z; }

}  // namespace granular
