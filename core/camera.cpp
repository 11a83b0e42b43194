#include "camera.h"

#include "error.h"
#include "sampling.h"

namespace granular {

Camera::Camera(const CameraDesc& desc, int width, int height)
    : toWorld_(desc.cameraToWorld), width_(width), height_(height), clipNear_(desc.clipNear), clipFar_(desc.clipFar),
      lensRadius_(desc.lensRadius), focusDistance_(desc.focusDistance), shutterOpen_(desc.shutterOpen),
      shutterClose_(desc.shutterClose) {
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

Ray Camera::generateRay(float px, float py, float lensU, float lensV) const {
  float sx = 2.0f * px / width_ - 1.0f;
  float sy = 1.0f - 2.0f * py / height_;
  Vec3 dCam(sx * halfW_ + offX_, sy * halfH_ + offY_, -1.0f);
  Vec3 oCam(0.0f);
  if (lensRadius_ > 0) {
    // Thin lens: from a lens point to where the pinhole ray meets the plane in focus.
    oCam = sampleConcentricDisk(lensU, lensV) * lensRadius_;
    dCam = dCam * focusDistance_ - oCam;
    dCam = dCam / -dCam.z;  // unit depth along the view axis, as the pinhole's
  }
  float invLen = 1.0f / length(dCam);
  Ray r;
  r.o = lensRadius_ > 0 ? toWorld_.point(oCam) : position_;
  r.d = normalize(toWorld_.vector(dCam));
  // The clip range is along the view axis; along this ray it scales by |dCam|.
  r.tmin = clipNear_ / invLen;
  r.tmax = clipFar_ / invLen;
  return r;
}

Ray Camera::sampleRay(int x, int y, Rng& rng) const {
  // y's jitter first: the order in which the former generateRay(x + u, y + u) call drew
  // them (GCC evaluates arguments right to left), so pinhole images are unchanged.
  float fy = float(y) + rng.next1D();
  float fx = float(x) + rng.next1D();
  Ray r;
  if (!hasLens()) {
    r = generateRay(fx, fy);
  } else {
    float lu = rng.next1D();
    float lv = rng.next1D();
    r = generateRay(fx, fy, lu, lv);
  }
  if (shutterClose_ > shutterOpen_) r.time = shutterOpen_ + (shutterClose_ - shutterOpen_) * rng.next1D();
  return r;
}

float Camera::viewDepth(const Vec3& p) const { return -toCamera_.point(p).z; }

}  // namespace granular
