#include "renderBuffer.h"

#include "renderParam.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "pxr/base/gf/half.h"
#include "pxr/base/gf/vec3f.h"
#include "pxr/base/gf/vec4f.h"

PXR_NAMESPACE_OPEN_SCOPE

HdGranularRenderBuffer::HdGranularRenderBuffer(SdfPath const& id) : HdRenderBuffer(id) {}

HdGranularRenderBuffer::~HdGranularRenderBuffer() = default;

void HdGranularRenderBuffer::Sync(HdSceneDelegate* sceneDelegate, HdRenderParam* renderParam, HdDirtyBits* dirtyBits) {
  if ((*dirtyBits & DirtyDescription) && renderParam)
    static_cast<HdGranularRenderParam*>(renderParam)->StopRenderForEdit();
  HdRenderBuffer::Sync(sceneDelegate, renderParam, dirtyBits);
}

void HdGranularRenderBuffer::Finalize(HdRenderParam* renderParam) {
  if (renderParam) static_cast<HdGranularRenderParam*>(renderParam)->StopRenderForEdit();
  HdRenderBuffer::Finalize(renderParam);
}

bool HdGranularRenderBuffer::Allocate(GfVec3i const& dims, HdFormat format, bool /*multiSampled*/) {
  _Deallocate();
  if (dims[2] != 1 || dims[0] <= 0 || dims[1] <= 0) {
    TF_WARN("hdGranular: render buffer %s: only 2-D buffers are supported", GetId().GetText());
    return false;
  }
  _width = unsigned(dims[0]);
  _height = unsigned(dims[1]);
  _format = format;
  _data.assign(size_t(_width) * _height * HdDataSizeOfFormat(format), 0);
  _converged = false;
  return true;
}

void HdGranularRenderBuffer::_Deallocate() {
  _width = _height = 0;
  _format = HdFormatInvalid;
  _data.clear();
  _mappers = 0;
  _converged = false;
}

void HdGranularRenderBuffer::Write(int x, int yFromTop, const float* v, int n) {
  if (_data.empty()) return;
  const size_t pixel = size_t(_height - 1 - yFromTop) * _width + size_t(x);
  const HdFormat component = HdGetComponentFormat(_format);
  const int count = int(HdGetComponentCount(_format));
  uint8_t* dst = _data.data() + pixel * HdDataSizeOfFormat(_format);
  for (int c = 0; c < count; ++c) {
    // Missing components: alpha 1, the rest 0.
    float value = c < n ? v[c] : (c == 3 ? 1.0f : 0.0f);
    switch (component) {
      case HdFormatFloat32: reinterpret_cast<float*>(dst)[c] = value; break;
      case HdFormatFloat16: reinterpret_cast<GfHalf*>(dst)[c] = GfHalf(value); break;
      case HdFormatUNorm8: dst[c] = uint8_t(std::clamp(value, 0.0f, 1.0f) * 255.0f + 0.5f); break;
      case HdFormatSNorm8: reinterpret_cast<int8_t*>(dst)[c] = int8_t(std::clamp(value, -1.0f, 1.0f) * 127.0f); break;
      case HdFormatInt32: reinterpret_cast<int32_t*>(dst)[c] = int32_t(value); break;
      default: break;
    }
  }
}

void HdGranularRenderBuffer::WriteInt(int x, int yFromTop, int value) {
  if (_data.empty()) return;
  if (HdGetComponentFormat(_format) == HdFormatInt32) {
    const size_t pixel = size_t(_height - 1 - yFromTop) * _width + size_t(x);
    reinterpret_cast<int32_t*>(_data.data() + pixel * HdDataSizeOfFormat(_format))[0] = value;
  } else {
    float f = float(value);
    Write(x, yFromTop, &f, 1);
  }
}

void HdGranularRenderBuffer::Clear(VtValue const& value) {
  if (_data.empty()) return;
  float v[4] = {0, 0, 0, 0};
  int n = 1;
  if (value.IsHolding<float>()) v[0] = value.UncheckedGet<float>();
  else if (value.IsHolding<double>()) v[0] = float(value.UncheckedGet<double>());
  else if (value.IsHolding<int>()) v[0] = float(value.UncheckedGet<int>());
  else if (value.IsHolding<GfVec3f>()) {
    GfVec3f c = value.UncheckedGet<GfVec3f>();
    v[0] = c[0]; v[1] = c[1]; v[2] = c[2];
    n = 3;
  } else if (value.IsHolding<GfVec4f>()) {
    GfVec4f c = value.UncheckedGet<GfVec4f>();
    v[0] = c[0]; v[1] = c[1]; v[2] = c[2]; v[3] = c[3];
    n = 4;
  }
  for (unsigned y = 0; y < _height; ++y)
    for (unsigned x = 0; x < _width; ++x) {
      if (HdGetComponentFormat(_format) == HdFormatInt32 && value.IsHolding<int>())
        WriteInt(int(x), int(y), value.UncheckedGet<int>());
      else
        Write(int(x), int(y), v, n);
    }
}

PXR_NAMESPACE_CLOSE_SCOPE
