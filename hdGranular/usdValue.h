// usdValue.h — a Hydra VtValue as core's plain record of a USD value (core/usd_values.h):
// numbers, strings, tokens and asset paths with USD's name of the held type. Hydra keeps
// no roles: a GfVec3f reads "color3f", the role it has wherever core reads three numbers.
// An unknown type keeps only its name, for core to report.
#ifndef HDGRANULAR_USD_VALUE_H
#define HDGRANULAR_USD_VALUE_H

#include "core/usd_values.h"
#include "pxr/base/vt/value.h"
#include "pxr/pxr.h"

PXR_NAMESPACE_OPEN_SCOPE

// Nothing (no value in the record) when v is empty.
std::optional<granular::UsdValue> HdGranularUsdValue(VtValue const& v);

PXR_NAMESPACE_CLOSE_SCOPE

#endif
