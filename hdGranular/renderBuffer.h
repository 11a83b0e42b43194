// renderBuffer.h — a CPU render buffer (an AOV) that the render loop fills.
//
// Contract: Allocate() sizes it for a format; Write() stores one pixel from floats (or
// an integer for Int32 formats), converting to the buffer's format (Float32, Float16,
// UNorm8, Int32; 1 to 4 components). Hydra reallocates (Sync) or frees (Finalize) a
// buffer only after the render loop was stopped. Row 0 is the bottom of the image (Hydra's
// convention). Converged is set by the renderer when its loop ends.
#ifndef HDGRANULAR_RENDER_BUFFER_H
#define HDGRANULAR_RENDER_BUFFER_H

#include <atomic>
#include <vector>

#include "pxr/imaging/hd/renderBuffer.h"
#include "pxr/pxr.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranularRenderBuffer final : public HdRenderBuffer {
 public:
  explicit HdGranularRenderBuffer(SdfPath const& id);
  ~HdGranularRenderBuffer() override;

  // Both stop the render loop first (it may be writing into this buffer).
  void Sync(HdSceneDelegate* sceneDelegate, HdRenderParam* renderParam, HdDirtyBits* dirtyBits) override;
  void Finalize(HdRenderParam* renderParam) override;
  bool Allocate(GfVec3i const& dimensions, HdFormat format, bool multiSampled) override;
  unsigned int GetWidth() const override { return _width; }
  unsigned int GetHeight() const override { return _height; }
  unsigned int GetDepth() const override { return 1; }
  HdFormat GetFormat() const override { return _format; }
  bool IsMultiSampled() const override { return false; }
  void* Map() override {
    ++_mappers;
    return _data.data();
  }
  void Unmap() override { --_mappers; }
  bool IsMapped() const override { return _mappers.load() != 0; }
  void Resolve() override {}
  bool IsConverged() const override { return _converged.load(); }
  void SetConverged(bool c) { _converged.store(c); }

  // (x, y) with y measured from the top of the image; n components.
  void Write(int x, int yFromTop, const float* values, int n);
  void WriteInt(int x, int yFromTop, int value);
  void Clear(VtValue const& value);

 private:
  void _Deallocate() override;
  unsigned int _width = 0, _height = 0;
  HdFormat _format = HdFormatInvalid;
  std::vector<uint8_t> _data;
  std::atomic<int> _mappers{0};
  std::atomic<bool> _converged{false};
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
