// denoise.h — the beauty denoised by Intel Open Image Denoise (OIDN), for both front ends
// (granular render --denoise, hdGranular's granular:denoise).
//
// Contract: denoise() takes w × h pixels of linear HDR radiance (RGB, row by row, three
// floats a pixel) with two guides of the same layout, the film's albedo AOV (the first
// hit's reflectance, in [0, 1]) and its normal AOV (unit, or zero where nothing was hit),
// and returns the denoised radiance in that layout: OIDN's "RT" filter with hdr on, on
// its CPU device (the same result on every machine, whatever GPU it has), the guides
// taken as noisy as the film holds them. The film's raw data is never changed: callers
// keep both. Input that is not finite, or arrays of the wrong size, are an InputError
// (object "denoise", attribute the array), never hidden. A failure of OIDN itself throws
// std::runtime_error with its message. Calls from several threads are serialised (one
// device per process, made on first use).
//
// OIDN is optional: found at configure time (GRANULAR_HAVE_OIDN); without it
// denoiserAvailable() is false, denoiserUnavailableReason() says why in one line and
// denoise() throws std::runtime_error with that line — front ends check first, say so
// once and show the image undenoised.
#pragma once

#include <atomic>
#include <string>
#include <vector>

namespace granular {

bool denoiserAvailable();
// Why not, in one line (empty when available).
std::string denoiserUnavailableReason();

std::vector<float> denoise(const std::vector<float>& color, const std::vector<float>& albedo,
                           const std::vector<float>& normal, int w, int h);

// The same into out (w·h·3 floats); returns false, out unspecified, when *cancel was set
// while it ran (OIDN checks it as it goes: a host's render restarting does not wait).
bool denoise(const float* color, const float* albedo, const float* normal, int w, int h, float* out,
             const std::atomic<bool>* cancel);

}  // namespace granular
