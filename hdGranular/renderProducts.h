// renderProducts.h — the active UsdRenderSettings prim's render products, written by the
// delegate itself when a render converges, so that a host that does not write products
// (usdrecord --renderSettingsPrimPath, which only checks that they exist) leaves the same
// files as `granular render` without -o: core describes each product (render_products.h)
// from Hydra's flattened values and writes it from the film with writeProduct.
//
// Contract: every settings bprim hands its products here on every sync (Hydra 24.08 may
// sync a settings prim before the host makes it active, and not again after: which one is
// active, and the frame, are set before each render from the scene globals); the render loop calls HdGranularWriteRenderProducts once per converged render, before it
// marks itself converged (a host that waits for convergence then finds the files). A
// product is written when its resolution is the rendered image's; one of another size is
// skipped with a warning (render it at its resolution: usdrecord --imageWidth W and a
// camera of the product's aspect), as is one whose data window the render did not cover.
// Errors (a missing folder) are reported with TF_RUNTIME_ERROR and write nothing; a file
// is whole or absent.
#ifndef HDGRANULAR_RENDER_PRODUCTS_H
#define HDGRANULAR_RENDER_PRODUCTS_H

#include <string>
#include <vector>

#include "core/film.h"
#include "core/render_products.h"
#include "core/scene.h"
#include "pxr/imaging/hd/renderSettings.h"
#include "pxr/pxr.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranularRenderer;

// Hydra's flattened product (its values already merged with the settings prim's, as
// UsdRender specifies) as core's description; nothing, with warnings, for a product core
// skips. granular::InputError naming the product or var for bad values.
std::optional<granular::RenderProductDesc> HdGranularProductDesc(HdRenderSettings::RenderProduct const& product,
                                                                  granular::UsdWarnings& warnings);

// What each settings prim asks `renderer` for (its sync hands them here): its products, or
// the error core found in them.
void HdGranularSetRenderProducts(HdGranularRenderer const* renderer, SdfPath const& settings,
                                 std::vector<granular::RenderProductDesc> products, std::string error = "");
// Withdraws a removed settings prim's products.
void HdGranularClearRenderProducts(HdGranularRenderer const* renderer, SdfPath const& settings);
// Before each render: the active settings prim (empty: none) and the current frame (NaN:
// none). granular::InputError naming the product or var when the active prim's products
// are bad or cannot be written (checkProductOutput), so the render is refused before it
// starts, as granular render refuses it.
void HdGranularActivateRenderProducts(HdGranularRenderer const* renderer, SdfPath const& active, double frame);
// The active prim's products hold a Cryptomatte layer (the film must keep its tables).
bool HdGranularActiveProductsNeedCryptomatte(HdGranularRenderer const* renderer);
// Writes the active prim's products from a converged film (Film::toImage: the crop's place
// in the image; the scene's Cryptomatte manifests in the header), logging each file
// written. The image is kept: a later frame of the same prim that is not rendered again
// (nothing changed) gets its products from it when it is activated.
void HdGranularWriteRenderProducts(HdGranularRenderer const* renderer, granular::Film const& film,
                                   granular::Scene const* scene);

PXR_NAMESPACE_CLOSE_SCOPE

#endif
