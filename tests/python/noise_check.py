"""Whether two renders of the same pixels agree within their Monte Carlo noise, judged by
the film's own standard errors (core/film.h: variance.R/G/B is the squared standard error
of each pixel's mean).

block_chi2 sums z^2 over 4 x 4 pixel blocks and R, G, B, z being the difference of the two
images' block means over its standard error (the pixels' variances summed: each sample
lands in its own pixel, so pixels are independent). When both images have the same
expectation each z is about standard normal (a block holds 16 pixels of many samples), so
the sum has expectation m, the number of terms, and a variance between 2m (independent
channels) and 6m (R, G and B of a block fully correlated: 3 chi^2 of m/3 terms).
noise_limit is five of those worst-case standard deviations above m: below it, "equal within
noise"; far above it, a difference the noise cannot explain."""
import math

import numpy as np

import granular_core as core

BLOCK = 4


def rgb_and_variance(path):
    """(RGB, variance of RGB), each (height, width, 3) float64, of an EXR the renderer wrote."""
    img = core.read_exr(str(path))
    px, ch = np.asarray(img.pixels, dtype=np.float64), list(img.channels)
    rgb = px[..., [ch.index(c) for c in ("R", "G", "B")]]
    var = px[..., [ch.index(c) for c in ("variance.R", "variance.G", "variance.B")]]
    return rgb, var


def _blocks(x):
    h, w = x.shape[0] // BLOCK * BLOCK, x.shape[1] // BLOCK * BLOCK
    return x[:h, :w].reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK, -1)


def block_chi2(a, var_a, b, var_b):
    """(sum of z^2, number of terms) of images a and b (height, width, 3) with their pixels'
    squared standard errors. Blocks where both images are noiseless and equal (a constant
    background) tell nothing and are left out; noiseless and different counts as infinite."""
    n = BLOCK * BLOCK
    d = _blocks(a - b).mean(axis=(1, 3))
    v = _blocks(var_a + var_b).sum(axis=(1, 3)) / (n * n)
    informative = v > 0
    if np.any((v == 0) & (d != 0)):
        return math.inf, int(informative.sum())
    return float(np.sum(d[informative] ** 2 / v[informative])), int(informative.sum())


def noise_limit(m):
    """m plus five standard deviations of the sum of m terms, channels fully correlated."""
    return m + 5.0 * math.sqrt(6.0 * m)
