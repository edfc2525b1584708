/* A tiny FMI 2.0 co-simulation FMU for tests: an ideal speed loop (motor speed = set point),
   a rigid screw (load = motor / k_r), and a doStep that fails from step `fail_after` on. */
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"
typedef struct { double t, w, th, kr; int n, fail_after;
                 const fmi2CallbackFunctions *cb; fmi2String name; } M;
#define LOG(m, st, msg) (m)->cb->logger((m)->cb->componentEnvironment, (m)->name, st, "log", msg)
const char* fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char* fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean l, size_t n, const fmi2String x[]) { return fmi2OK; }
fmi2Component fmi2Instantiate(fmi2String name, fmi2Type t, fmi2String guid, fmi2String loc,
                              const fmi2CallbackFunctions* cb, fmi2Boolean v, fmi2Boolean l) {
  M *m = calloc(1, sizeof(M)); m->kr = 314.1592653589793; m->fail_after = -1; m->cb = cb; m->name = name; return m; }
void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean a, fmi2Real b, fmi2Real s, fmi2Boolean d, fmi2Real e) { return fmi2OK; }
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
  M *m = c; for (size_t i = 0; i < n; i++) switch (vr[i]) {
    case 0: v[i] = m->w; break; case 1: v[i] = 0; break; case 2: v[i] = m->th; break;
    case 3: v[i] = m->w; break; case 4: v[i] = m->th / m->kr; break; case 5: v[i] = 0; break;
    case 10: v[i] = m->kr; break; default: return fmi2Error; }
  return fmi2OK; }
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
  M *m = c; for (size_t i = 0; i < n; i++) { if (vr[i] != 20) return fmi2Error; v[i] = m->fail_after; } return fmi2OK; }
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) { return fmi2Error; }
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) { return fmi2Error; }
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
  M *m = c; for (size_t i = 0; i < n; i++) { if (vr[i] == 0) m->w = v[i]; else if (vr[i] != 1) return fmi2Error; } return fmi2OK; }
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
  M *m = c; for (size_t i = 0; i < n; i++) { if (vr[i] != 20) return fmi2Error; m->fail_after = v[i]; } return fmi2OK; }
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) { return fmi2Error; }
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) { return fmi2Error; }
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate* s) { return fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { return fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate* s) { return fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) { return fmi2Error; }
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) { return fmi2Error; }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate* s) { return fmi2Error; }
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference a[], size_t na,
  const fmi2ValueReference b[], size_t nb, const fmi2Real d[], fmi2Real e[]) { return fmi2Error; }
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[], const fmi2Real v[]) { return fmi2Error; }
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[], fmi2Real v[]) { return fmi2Error; }
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean x) {
  M *m = c;
  if (m->fail_after >= 0 && m->n >= m->fail_after) { LOG(m, fmi2Error, "doStep: the tiny FMU fails here on purpose"); return fmi2Error; }
  m->th += m->w * h; m->t = t + h; m->n++; return fmi2OK; }
fmi2Status fmi2CancelStep(fmi2Component c) { return fmi2Error; }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status* v) { return fmi2Error; }
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real* v) { return fmi2Error; }
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer* v) { return fmi2Error; }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean* v) { return fmi2Error; }
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String* v) { return fmi2Error; }
