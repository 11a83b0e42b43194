// medium.h — the homogeneous medium equivalent to an aggregate of grains: its world-space
// RTE and diffusion parameters, what VPT (vpt.h), DA (diffusion.h) and the scene read.
//
// Contract: tt.h derives them from the grain prototypes' teleportation transport
// (deriveMedium, aggregateMedium), where the formulas and their degenerate cases are;
// vpt.h's mediumFromRte() makes them from given RTE parameters. Lengths are world
// lengths, coefficients per world length, every per-channel quantity RGB.
#pragma once

#include <array>

#include "math.h"
#include "tt.h"

namespace granular {

// World-space RTE and diffusion parameters of one aggregate (Meng et al. 2015).
struct MediumParams {
  float grainRadius = 0, packingRate = 0;
  float sigmaB = 0;                       // Dixmier, 1/world length
  GrainTransport combined;                // the mixture's intra-grain statistics (unit radius)
  Vec3 lambdaBeta, lambdaT;               // world lengths
  Vec3 sigmaT, albedo;                    // σ_t, α_s
  std::array<PhaseTable, 3> phase;
  Vec3 g;
  Vec3 sigmaSReduced, sigmaTReduced, albedoReduced;  // σ'_s, σ'_t, α'_s
  Vec3 sigmaA, sigmaTr;                   // σ_a = (1−α_s)σ_t, σ_tr = sqrt(3 σ_a σ'_t)
  Vec3 meanFreePath() const { return lambdaT; }
};

}  // namespace granular
