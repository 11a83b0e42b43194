#include "denoise.h"

#include <algorithm>
#include <cmath>
#include <mutex>
#include <stdexcept>
#include <utility>

#include "error.h"

#if defined(GRANULAR_HAVE_OIDN) && __has_include(<OpenImageDenoise/oidn.h>)
#include <OpenImageDenoise/oidn.h>
#elif defined(GRANULAR_HAVE_OIDN)
// The library's C interface, for builds against a library shipped without its headers
// (the pyoidn wheel): only the entry points and enumerators used below.
extern "C" {
typedef struct OIDNDeviceImpl* OIDNDevice;
typedef struct OIDNFilterImpl* OIDNFilter;
typedef enum { OIDN_DEVICE_TYPE_CPU = 1 } OIDNDeviceType;
typedef enum { OIDN_ERROR_NONE = 0, OIDN_ERROR_CANCELLED = 6 } OIDNError;
typedef enum { OIDN_FORMAT_FLOAT3 = 3 } OIDNFormat;
typedef bool (*OIDNProgressMonitorFunction)(void* userPtr, double n);
OIDNDevice oidnNewDevice(OIDNDeviceType type);
void oidnCommitDevice(OIDNDevice device);
void oidnReleaseDevice(OIDNDevice device);
OIDNError oidnGetDeviceError(OIDNDevice device, const char** outMessage);
OIDNFilter oidnNewFilter(OIDNDevice device, const char* type);
void oidnSetSharedFilterImage(OIDNFilter filter, const char* name, void* devPtr, OIDNFormat format, size_t width,
                              size_t height, size_t byteOffset, size_t pixelByteStride, size_t rowByteStride);
void oidnSetFilterBool(OIDNFilter filter, const char* name, bool value);
void oidnSetFilterProgressMonitorFunction(OIDNFilter filter, OIDNProgressMonitorFunction func, void* userPtr);
void oidnCommitFilter(OIDNFilter filter);
void oidnExecuteFilter(OIDNFilter filter);
void oidnReleaseFilter(OIDNFilter filter);
}
#endif

namespace granular {

namespace {

void checkInput(const float* v, const char* name, int w, int h) {
  if (!v) throw InputError("denoise", name, "missing");
  for (size_t i = 0; i < size_t(w) * h * 3; ++i)
    if (!std::isfinite(v[i]))
      throw InputError("denoise", name, str("not finite at pixel (", (i / 3) % size_t(w), ", ", i / 3 / size_t(w), ")"));
}

#ifdef GRANULAR_HAVE_OIDN
std::mutex& deviceMutex() {
  static std::mutex m;
  return m;
}

// The process's device (made on first use, under deviceMutex), or null with the reason.
OIDNDevice device(std::string* reason) {
  static OIDNDevice dev = nullptr;
  static std::string failure;
  static bool tried = false;
  if (!tried) {
    tried = true;
    dev = oidnNewDevice(OIDN_DEVICE_TYPE_CPU);
    if (dev) oidnCommitDevice(dev);
    const char* message = nullptr;
    if (!dev || oidnGetDeviceError(dev, &message) != OIDN_ERROR_NONE) {
      failure = str("Intel Open Image Denoise has no CPU device here: ", message ? message : "unknown error");
      if (dev) oidnReleaseDevice(dev);
      dev = nullptr;
    }
  }
  if (reason) *reason = failure;
  return dev;
}

bool keepGoing(void* cancel, double) { return !static_cast<const std::atomic<bool>*>(cancel)->load(); }
#endif

}  // namespace

std::string denoiserUnavailableReason() {
#ifdef GRANULAR_HAVE_OIDN
  // Settled by the first call (the device is made once): later calls take no lock.
  static const std::string reason = [] {
    std::lock_guard<std::mutex> lock(deviceMutex());
    std::string r;
    device(&r);
    return r;
  }();
  return reason;
#else
  return "this build has no Intel Open Image Denoise (none was found when it was configured)";
#endif
}

bool denoiserAvailable() { return denoiserUnavailableReason().empty(); }

bool denoise(const float* color, const float* albedo, const float* normal, int w, int h, float* out,
             const std::atomic<bool>* cancel) {
  if (w <= 0 || h <= 0) throw InputError("denoise", "size", str(w, "x", h, " has no pixels"));
  checkInput(color, "color", w, h);
  checkInput(albedo, "albedo", w, h);
  checkInput(normal, "normal", w, h);
#ifdef GRANULAR_HAVE_OIDN
  std::lock_guard<std::mutex> lock(deviceMutex());
  std::string reason;
  OIDNDevice dev = device(&reason);
  if (!dev) throw std::runtime_error("denoise: " + reason);
  OIDNFilter filter = oidnNewFilter(dev, "RT");
  const size_t pixel = 3 * sizeof(float), row = pixel * size_t(w);
  // OIDN reads the inputs only; its interface takes them as non-const.
  oidnSetSharedFilterImage(filter, "color", const_cast<float*>(color), OIDN_FORMAT_FLOAT3, w, h, 0, pixel, row);
  oidnSetSharedFilterImage(filter, "albedo", const_cast<float*>(albedo), OIDN_FORMAT_FLOAT3, w, h, 0, pixel, row);
  oidnSetSharedFilterImage(filter, "normal", const_cast<float*>(normal), OIDN_FORMAT_FLOAT3, w, h, 0, pixel, row);
  oidnSetSharedFilterImage(filter, "output", out, OIDN_FORMAT_FLOAT3, w, h, 0, pixel, row);
  oidnSetFilterBool(filter, "hdr", true);
  if (cancel) oidnSetFilterProgressMonitorFunction(filter, keepGoing, const_cast<std::atomic<bool>*>(cancel));
  oidnCommitFilter(filter);
  oidnExecuteFilter(filter);
  oidnReleaseFilter(filter);
  const char* message = nullptr;
  const OIDNError err = oidnGetDeviceError(dev, &message);
  if (err == OIDN_ERROR_CANCELLED || (cancel && cancel->load())) return false;
  if (err != OIDN_ERROR_NONE)
    throw std::runtime_error(str("denoise: Intel Open Image Denoise failed: ", message ? message : "unknown error"));
  return true;
#else
  (void)out;
  (void)cancel;
  throw std::runtime_error("denoise: " + denoiserUnavailableReason());
#endif
}

std::vector<float> denoise(const std::vector<float>& color, const std::vector<float>& albedo,
                           const std::vector<float>& normal, int w, int h) {
  const size_t n = size_t(std::max(w, 0)) * size_t(std::max(h, 0)) * 3;
  const std::pair<const std::vector<float>*, const char*> inputs[] = {{&color, "color"}, {&albedo, "albedo"},
                                                                       {&normal, "normal"}};
  for (auto const& [v, name] : inputs)
    if (v->size() != n) throw InputError("denoise", name, str(v->size(), " floats for ", w, "x", h, " RGB pixels"));
  std::vector<float> out(n);
  denoise(color.data(), albedo.data(), normal.data(), w, h, out.data(), nullptr);
  return out;
}

}  // namespace granular
