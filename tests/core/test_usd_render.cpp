// test_usd_render.cpp — UsdRender settings and products on plain records: resolution and
// the data window, with UsdRender's product-over-settings rule.
#include <gtest/gtest.h>

#include "core/error.h"
#include "core/usd_render.h"
#include "usd_records.h"

using namespace granular;
using namespace granular::test;

namespace {

std::string windowError(const UsdPrimRecord* settings, const UsdPrimRecord* product) {
  UsdWarnings w;
  return inputErrorOf([&] { dataWindowFromUsd(settings, product, 40, 30, w); });
}

}  // namespace

TEST(UsdRender, ResolutionIsReadAndChecked) {
  EXPECT_FALSE(resolutionFromUsd(usdRecord("/Render", "RenderSettings")));
  const auto res = resolutionFromUsd(usdRecord("/Render", "RenderSettings", {{"resolution", usdNumbers("int2", {64, 48})}}));
  ASSERT_TRUE(res);
  EXPECT_EQ(res->first, 64);
  EXPECT_EQ(res->second, 48);
  try {
    resolutionFromUsd(usdRecord("/Render", "RenderSettings", {{"resolution", usdNumbers("int2", {0, 48})}}));
    FAIL();
  } catch (const InputError& e) {
    EXPECT_STREQ(e.what(), "/Render.resolution: (0, 48) is outside [1, 32768] x [1, 32768]");
  }
}

TEST(UsdRender, TheProductsDataWindowWinsOverTheSettingsPrims) {
  const UsdPrimRecord settings =
      usdRecord("/Render", "RenderSettings", {{"dataWindowNDC", usdNumbers("float4", {0, 0, 0.5, 1})}});
  const UsdPrimRecord own = usdRecord("/Render/Product", "RenderProduct",
                                      {{"dataWindowNDC", usdNumbers("float4", {0.25, 0.5, 0.5, 1})}});
  const UsdPrimRecord inherits = usdRecord("/Render/Product", "RenderProduct");
  UsdWarnings w;
  const auto a = dataWindowFromUsd(&settings, &own, 40, 30, w);
  ASSERT_TRUE(a);
  EXPECT_EQ(*a, (PixelWindow{10, 20, 0, 15}));
  const auto b = dataWindowFromUsd(&settings, &inherits, 40, 30, w);
  ASSERT_TRUE(b);
  EXPECT_EQ(*b, (PixelWindow{0, 20, 0, 30}));
  EXPECT_TRUE(w.empty());
  // No product: nothing is cropped, and the settings prim's window is said to be ignored.
  EXPECT_FALSE(dataWindowFromUsd(&settings, nullptr, 40, 30, w));
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0].rfind("/Render.dataWindowNDC: ignored", 0), 0u);
  // The whole image is no crop; overscan is clipped with a warning.
  w.clear();
  const UsdPrimRecord whole = usdRecord("/P", "RenderProduct", {{"dataWindowNDC", usdNumbers("float4", {0, 0, 1, 1})}});
  EXPECT_FALSE(dataWindowFromUsd(nullptr, &whole, 40, 30, w));
  const UsdPrimRecord over = usdRecord("/P", "RenderProduct", {{"dataWindowNDC", usdNumbers("float4", {-0.5, 0, 0.5, 1})}});
  EXPECT_EQ(*dataWindowFromUsd(nullptr, &over, 40, 30, w), (PixelWindow{0, 20, 0, 30}));
  EXPECT_EQ(w.size(), 1u);
}

TEST(UsdRender, DataWindowsThatCoverNothingAreRefusedByName) {
  const UsdPrimRecord empty = usdRecord("/P", "RenderProduct", {{"dataWindowNDC", usdNumbers("float4", {0.5, 0, 0.2, 1})}});
  EXPECT_EQ(windowError(nullptr, &empty), "/P.dataWindowNDC: (0.5, 0, 0.2, 1) is empty: xmin < xmax and ymin < ymax are needed");
  const UsdPrimRecord outside = usdRecord("/P", "RenderProduct", {{"dataWindowNDC", usdNumbers("float4", {1.1, 0, 1.5, 1})}});
  EXPECT_EQ(windowError(nullptr, &outside), "/P.dataWindowNDC: (1.1, 0, 1.5, 1) covers no pixel of the 40x30 image");
  const UsdPrimRecord nan = usdRecord("/P", "RenderProduct", {{"dataWindowNDC", usdNumbers("float4", {NAN, 0, 1, 1})}});
  EXPECT_EQ(windowError(nullptr, &nan).rfind("/P.dataWindowNDC: (nan, 0, 1, 1) is not four finite numbers", 0), 0u);
}
