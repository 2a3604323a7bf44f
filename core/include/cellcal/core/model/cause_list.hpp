// The causes cellcal knows, one line each: X(enumerator, file stem). A cause is one file, core/src/model/causes/
// <stem>.cpp, which defines `const CauseModel& <stem>Cause()` (cause.hpp), and one line here; `enum class Cause`
// (model_extension.hpp) and the registry (causes/registry.cpp) are made from this list. The order is the order diagnose
// tries them in and lists them by; new causes go at the end.
#pragma once

#define CELLCAL_CAUSES(X)                        \
  X(kJointCompliance, jointCompliance)           \
  X(kThermalDrift, thermalDrift)                 \
  X(kCyclicTransmission, cyclicTransmission)     \
  X(kJointScale, jointScale)                     \
  X(kBacklash, backlash)                         \
  X(kLinkDeflection, linkDeflection)             \
  X(kFrameDrift, frameDrift)
