// MuJoCo's C engine as an XLA FFI custom call (CPU): jaxenvs' native engine.
//
// One call steps a batch of simulations of one registered model, each from its own full
// input state, and writes the fields it asks for. Python (jaxenvs/physics/cengine.py) builds the
// call; this file holds no Python.
//
// Contract of the FFI target "jaxenvs_mj_step":
//   attributes  model    the key a model was registered under (jaxenvs_register_model)
//               substeps mj_step calls with the controls held; 0: one mj_forward
//               threads  threads of the batch's pool (the caller's included)
//               serial_work  below this many (sims x substeps x dofs) one thread steps all
//               inputs   comma-separated mjData fields read, in argument order ("time",
//                        "qpos", ...: the state a step reads)
//               params   comma-separated mjModel fields given per simulation, after inputs
//               outputs  comma-separated mjData fields written, in result order;
//                        "actuator_moment" is written dense (nu x nv), as MJX holds it
//   arguments   one buffer per input then per param, each (batch..., field size) with the
//               same leading batch dims; float32 or float64 (eq_active: bool)
//   results     one buffer per output, (batch..., field size), float32 or float64
// Every simulation is stepped on its own (MuJoCo's mjBatch: per-thread mjData, per-
// simulation model fields), so results are the same bit for bit at any thread count.
// Derived outputs are zeroed before the step, so a field this step does not compute is 0
// (as in a fresh mjx.Data), never another simulation's value. A simulation that raised a
// bad-state warning (MuJoCo resets such a state and carries on) or an error comes back
// with every output NaN but time.

#include <mujoco/mjbatch.h>
#include <mujoco/mjxmacro.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

// ------------------------------------------------------------------ mjData fields by name

struct DataField {
  const char* name;
  size_t offset;       // of the pointer member in mjData
  size_t rows_offset;  // of the mjModel size member that counts its rows
  int cols;
  int elem_size;
  bool is_num;  // mjtNum (else int or mjtBool)
};

// the size of any mjData field: rows (an mjModel member) x cols
#define X(type, name, nr, nc)                                                       \
  DataField{#name,                                                                  \
            offsetof(mjData, name),                                                 \
            offsetof(mjModel, nr),                                                  \
            static_cast<int>(nc),                                                   \
            static_cast<int>(sizeof(type)),                                         \
            std::is_same<type, mjtNum>::value},
#define XNV X
const DataField kDataFields[] = {MJDATA_POINTERS};
#undef XNV
#undef X

const DataField* FindDataField(std::string_view name) {
  for (const DataField& f : kDataFields) {
    if (name == f.name) return &f;
  }
  return nullptr;
}

int64_t FieldSize(const mjModel* m, const DataField& f) {
  auto rows = *reinterpret_cast<const mjtSize*>(reinterpret_cast<const char*>(m) +
                                                f.rows_offset);
  return static_cast<int64_t>(rows) * f.cols;
}

template <typename T>
T* FieldPtr(mjData* d, const DataField& f) {
  return *reinterpret_cast<T**>(reinterpret_cast<char*>(d) + f.offset);
}

// ------------------------------------------------------------------ a call's layout

enum class Kind { kTime, kCopy, kBool, kDenseMoment };

struct Slot {  // one argument or result
  Kind kind = Kind::kCopy;
  const DataField* field = nullptr;  // kCopy, kBool, kDenseMoment
  std::string name;
  int64_t size = 0;  // elements per simulation
};

struct Plan {
  std::vector<Slot> inputs, outputs;
  std::vector<std::string> params;
  std::vector<int64_t> param_sizes;
  std::vector<const DataField*> zeroed;  // derived outputs, cleared before a step
};

std::vector<std::string> Split(std::string_view s) {
  std::vector<std::string> out;
  while (!s.empty()) {
    size_t comma = s.find(',');
    out.emplace_back(s.substr(0, comma));
    if (comma == std::string_view::npos) break;
    s.remove_prefix(comma + 1);
  }
  return out;
}

const std::set<std::string>& StateFields() {
  static const auto* fields = new std::set<std::string>{
      "time", "qpos", "qvel", "act", "qacc_warmstart", "ctrl", "qfrc_applied",
      "xfrc_applied", "eq_active", "mocap_pos", "mocap_quat", "userdata"};
  return *fields;
}

// ------------------------------------------------------------------ conversions

bool IsFloat(ffi::DataType t) { return t == ffi::DataType::F32 || t == ffi::DataType::F64; }

void Load(const void* src, ffi::DataType t, int64_t offset, mjtNum* dst, int64_t n) {
  if (t == ffi::DataType::F32) {
    const float* s = static_cast<const float*>(src) + offset;
    for (int64_t i = 0; i < n; ++i) dst[i] = s[i];
  } else {
    std::memcpy(dst, static_cast<const double*>(src) + offset, n * sizeof(double));
  }
}

void Store(const mjtNum* src, void* dst, ffi::DataType t, int64_t offset, int64_t n) {
  if (t == ffi::DataType::F32) {
    float* o = static_cast<float*>(dst) + offset;
    for (int64_t i = 0; i < n; ++i) o[i] = static_cast<float>(src[i]);
  } else {
    std::memcpy(static_cast<double*>(dst) + offset, src, n * sizeof(double));
  }
}

void StoreNaN(void* dst, ffi::DataType t, int64_t offset, int64_t n) {
  if (t == ffi::DataType::F32) {
    float* o = static_cast<float*>(dst) + offset;
    for (int64_t i = 0; i < n; ++i) o[i] = std::numeric_limits<float>::quiet_NaN();
  } else {
    double* o = static_cast<double*>(dst) + offset;
    for (int64_t i = 0; i < n; ++i) o[i] = std::numeric_limits<double>::quiet_NaN();
  }
}

ffi::Error Fail(const std::string& message) {
  return ffi::Error::InvalidArgument("jaxenvs native engine: " + message);
}

// ------------------------------------------------------------------ engines

struct Pool {  // one mjBatch of a thread count, grown to the largest batch seen
  mjBatch* batch = nullptr;
  int nsim = 0;
  std::set<std::string> expanded;
};

struct Engine {
  mjModel* model = nullptr;
  // guards the maps below; a call holds it only to look up its plan and take a pool, so
  // calls from several devices at once each step on a pool of their own
  std::mutex mu;
  std::map<int, std::vector<std::unique_ptr<Pool>>> idle;  // free pools by thread count
  std::map<std::string, Plan> plans;
  std::map<std::string, std::vector<mjtNum>> defaults;  // model values of params fields
  ~Engine() {
    for (auto& [n, pools] : idle) {
      for (auto& pool : pools) {
        if (pool->batch) mjb_deleteBatch(pool->batch);
      }
    }
    if (model) mj_deleteModel(model);
  }
};

// A pool of nthread threads for one call, returned to the engine when the call ends.
class PoolLease {
 public:
  PoolLease(Engine* e, int nthread) : e_(e), nthread_(nthread) {
    std::lock_guard<std::mutex> lock(e->mu);
    auto& pools = e->idle[nthread];
    if (pools.empty()) {
      pool_ = std::make_unique<Pool>();
    } else {
      pool_ = std::move(pools.back());
      pools.pop_back();
    }
  }
  ~PoolLease() {
    std::lock_guard<std::mutex> lock(e_->mu);
    e_->idle[nthread_].push_back(std::move(pool_));
  }
  Pool& operator*() { return *pool_; }

 private:
  Engine* e_;
  int nthread_;
  std::unique_ptr<Pool> pool_;
};

std::mutex registry_mu;
std::map<std::string, std::unique_ptr<Engine>>& Registry() {
  static auto* registry = new std::map<std::string, std::unique_ptr<Engine>>();
  return *registry;
}

Engine* FindEngine(std::string_view key) {
  std::lock_guard<std::mutex> lock(registry_mu);
  auto it = Registry().find(std::string(key));
  return it == Registry().end() ? nullptr : it->second.get();
}

// The layout of a call signature, checked against the model once and kept.
ffi::ErrorOr<const Plan*> PlanFor(Engine* e, std::string_view inputs, std::string_view params,
                                  std::string_view outputs) {
  std::string key = std::string(inputs) + "|" + std::string(params) + "|" +
                    std::string(outputs);
  auto it = e->plans.find(key);
  if (it != e->plans.end()) return &it->second;
  const mjModel* m = e->model;
  Plan plan;
  auto slot = [&](const std::string& name, bool input) -> ffi::ErrorOr<Slot> {
    Slot s;
    s.name = name;
    if (name == "time") {
      s.kind = Kind::kTime;
      s.size = 1;
      return s;
    }
    if (input && !StateFields().count(name)) {
      return ffi::Unexpected(Fail("'" + name + "' is not a state field a step reads"));
    }
    if (!input && name == "actuator_moment") {
      s.kind = Kind::kDenseMoment;
      s.field = FindDataField(name);
      s.size = static_cast<int64_t>(m->nu) * m->nv;
      return s;
    }
    s.field = FindDataField(name);
    if (input && name == "eq_active" && s.field) {
      s.kind = Kind::kBool;  // read from a bool (or uint8) buffer
    } else if (!s.field || !s.field->is_num) {
      return ffi::Unexpected(Fail("'" + name + "' is not a floating-point mjData field"));
    }
    s.size = FieldSize(m, *s.field);
    return s;
  };
  for (const std::string& name : Split(inputs)) {
    auto s = slot(name, true);
    if (s.has_error()) return ffi::Unexpected(s.error());
    plan.inputs.push_back(*s);
  }
  for (const std::string& name : Split(outputs)) {
    auto s = slot(name, false);
    if (s.has_error()) return ffi::Unexpected(s.error());
    if (s->kind != Kind::kTime && !StateFields().count(name)) plan.zeroed.push_back(s->field);
    plan.outputs.push_back(*s);
  }
  plan.params = Split(params);
  return &e->plans.emplace(key, std::move(plan)).first->second;
}

// The plan of this thread's last call, so that a program stepping the same model call
// after call finds it without a lock or an allocation. Engines (one per model) and plans
// are never freed, so the pointers stay valid; the strings are compared in full (attribute
// storage may be reused by another program).
struct LastCall {
  std::string inputs, params, outputs;
  Engine* engine = nullptr;
  const Plan* plan = nullptr;
};

ffi::ErrorOr<const Plan*> CachedPlan(Engine* e, std::string_view inputs, std::string_view params,
                                     std::string_view outputs) {
  thread_local LastCall last;
  if (last.engine == e && last.inputs == inputs && last.params == params &&
      last.outputs == outputs) {
    return last.plan;
  }
  const Plan* plan;
  {
    std::lock_guard<std::mutex> lock(e->mu);
    auto planned = PlanFor(e, inputs, params, outputs);
    if (planned.has_error()) return planned;
    plan = *planned;
  }
  last.inputs.assign(inputs);
  last.params.assign(params);
  last.outputs.assign(outputs);
  last.engine = e;
  last.plan = plan;
  return plan;
}

Engine* CachedEngine(std::string_view model) {
  thread_local std::string last_key;
  thread_local Engine* last_engine = nullptr;
  if (last_engine && last_key == model) return last_engine;
  Engine* e = FindEngine(model);
  if (e) {
    last_key.assign(model);
    last_engine = e;
  }
  return e;
}

// ------------------------------------------------------------------ one simulation

struct CallArgs {
  const Plan* plan;
  int substeps;
  std::vector<const void*> in;
  std::vector<ffi::DataType> in_type;
  std::vector<void*> out;
  std::vector<ffi::DataType> out_type;
};

// warnings that mean a step went wrong; MuJoCo resets a bad state (zeroing every counter)
// and carries on
constexpr int kBadWarnings[] = {mjWARN_CONTACTFULL, mjWARN_CNSTRFULL, mjWARN_BADQPOS,
                                mjWARN_BADQVEL, mjWARN_BADQACC, mjWARN_BADCTRL};

void WriteNaN(const CallArgs& a, int sim) {
  for (size_t k = 0; k < a.plan->outputs.size(); ++k) {
    const Slot& s = a.plan->outputs[k];
    if (s.kind == Kind::kTime) continue;
    StoreNaN(a.out[k], a.out_type[k], sim * s.size, s.size);
  }
}

void RunOne(const mjModel* m, mjData* d, int sim, void* arg) {
  const CallArgs& a = *static_cast<const CallArgs*>(arg);
  const Plan& plan = *a.plan;
  // the state this simulation starts from
  for (size_t k = 0; k < plan.inputs.size(); ++k) {
    const Slot& s = plan.inputs[k];
    if (s.kind == Kind::kTime) {
      Load(a.in[k], a.in_type[k], sim, &d->time, 1);
    } else if (s.kind == Kind::kBool) {
      const uint8_t* src = static_cast<const uint8_t*>(a.in[k]) + sim * s.size;
      mjtBool* dst = FieldPtr<mjtBool>(d, *s.field);
      for (int64_t i = 0; i < s.size; ++i) dst[i] = src[i] ? 1 : 0;
    } else {
      Load(a.in[k], a.in_type[k], sim * s.size, FieldPtr<mjtNum>(d, *s.field), s.size);
    }
  }
  for (const DataField* f : plan.zeroed) {
    std::memset(FieldPtr<char>(d, *f), 0, FieldSize(m, *f) * f->elem_size);
  }
  // counters start at 1 so that MuJoCo does not print (it prints a warning's first time)
  for (int w : kBadWarnings) d->warning[w].number = 1;
  double time0 = d->time;
  if (a.substeps == 0) {
    mj_forward(m, d);
  } else {
    for (int i = 0; i < a.substeps; ++i) mj_step(m, d);
  }
  bool bad = false;  // a warning raised (counter above 1) or a reset (counters zeroed)
  for (int w : kBadWarnings) bad |= d->warning[w].number != 1;
  for (size_t k = 0; k < plan.outputs.size(); ++k) {
    const Slot& s = plan.outputs[k];
    if (s.kind == Kind::kTime) {
      double t = bad ? time0 + a.substeps * m->opt.timestep : d->time;
      Store(&t, a.out[k], a.out_type[k], sim, 1);
    } else if (bad) {
      StoreNaN(a.out[k], a.out_type[k], sim * s.size, s.size);
    } else if (s.kind == Kind::kDenseMoment) {
      // MJX holds actuator_moment dense (nu x nv); MuJoCo as compressed rows
      std::vector<mjtNum> dense(s.size, 0.0);
      for (int i = 0; i < m->nu; ++i) {
        for (int j = 0; j < d->moment_rownnz[i]; ++j) {
          int adr = d->moment_rowadr[i] + j;
          dense[static_cast<size_t>(i) * m->nv + d->moment_colind[adr]] =
              d->actuator_moment[adr];
        }
      }
      Store(dense.data(), a.out[k], a.out_type[k], sim * s.size, s.size);
    } else {
      Store(FieldPtr<mjtNum>(d, *s.field), a.out[k], a.out_type[k], sim * s.size, s.size);
    }
  }
}

// ------------------------------------------------------------------ MuJoCo's timers

// MuJoCo's Python bindings install a default clock as mjcb_time at import (and again on
// mujoco.set_mjcb_time(None)), which turns on MuJoCo's per-stage timers for the whole
// process: 20-30 clock reads a step, a quarter of a small model's step. Our batches report
// no timers, so each call turns that default clock off; a clock someone installed on
// purpose (mujoco.set_mjcb_time(fn)) is another pointer, kept.
std::atomic<mjfTime> default_clock{nullptr};

void QuietDefaultClock() {
  mjfTime clock = default_clock.load(std::memory_order_relaxed);
  if (clock && mjcb_time == clock) mjcb_time = nullptr;
}

// ------------------------------------------------------------------ the handler

ffi::Error StepImpl(std::string_view model_key, int64_t substeps, int64_t threads,
                    int64_t serial_work, std::string_view inputs, std::string_view params,
                    std::string_view outputs, ffi::RemainingArgs args,
                    ffi::RemainingRets rets) {
  Engine* e = CachedEngine(model_key);
  if (!e) {
    return ffi::Error(
        ffi::ErrorCode::kFailedPrecondition,
        "jaxenvs native engine: no MuJoCo model " + std::string(model_key) +
            " is registered in this process. A compiled program that steps a model under "
            "physics='c' runs in a process that built that env first (jaxenvs.make).");
  }
  if (substeps < 0 || threads < 1) return Fail("substeps must be >= 0 and threads >= 1");
  QuietDefaultClock();
  auto planned = CachedPlan(e, inputs, params, outputs);
  if (planned.has_error()) return planned.error();
  const Plan* plan = *planned;
  size_t nin = plan->inputs.size(), npar = plan->params.size();
  if (args.size() != nin + npar || rets.size() != plan->outputs.size()) {
    return Fail("argument or result count does not match the call's field lists");
  }
  const mjModel* m = e->model;

  CallArgs call;
  call.plan = plan;
  call.substeps = static_cast<int>(substeps);
  call.in.reserve(nin);
  call.in_type.reserve(nin);
  call.out.reserve(plan->outputs.size());
  call.out_type.reserve(plan->outputs.size());
  int64_t nsim = -1;
  auto batch_of = [&](const ffi::AnyBuffer& buf, int64_t size, const std::string& name)
      -> ffi::Error {
    int64_t count = static_cast<int64_t>(buf.element_count());
    int64_t n = size ? count / size : -1;
    if (size == 0) {
      // an empty field carries no batch size; its buffer must be empty too
      return count == 0 ? ffi::Error::Success() : Fail("'" + name + "' must be empty");
    }
    if (count % size) return Fail("'" + name + "' has a size that is not a whole batch");
    if (nsim >= 0 && n != nsim) return Fail("'" + name + "' has another batch size");
    nsim = n;
    return ffi::Error::Success();
  };
  for (size_t k = 0; k < nin; ++k) {
    auto buf = args.get<ffi::AnyBuffer>(k);
    if (buf.has_error()) return buf.error();
    const Slot& s = plan->inputs[k];
    bool boolean = s.kind == Kind::kBool;
    if (boolean ? buf->element_type() != ffi::DataType::PRED && buf->element_type() != ffi::DataType::U8
                : !IsFloat(buf->element_type())) {
      return Fail("input '" + s.name + "' has an unsupported dtype");
    }
    if (auto err = batch_of(*buf, s.size, s.name); err.failure()) return err;
    call.in.push_back(buf->untyped_data());
    call.in_type.push_back(buf->element_type());
  }
  std::vector<ffi::AnyBuffer> param_bufs;
  for (size_t k = 0; k < npar; ++k) {
    auto buf = args.get<ffi::AnyBuffer>(nin + k);
    if (buf.has_error()) return buf.error();
    if (!IsFloat(buf->element_type())) return Fail("params must be floating point");
    param_bufs.push_back(*buf);
  }
  for (size_t k = 0; k < plan->outputs.size(); ++k) {
    auto buf = rets.get<ffi::AnyBuffer>(k);
    if (buf.has_error()) return buf.error();
    const Slot& s = plan->outputs[k];
    if (!IsFloat((*buf)->element_type())) return Fail("outputs must be floating point");
    if (auto err = batch_of(**buf, s.size, s.name); err.failure()) return err;
    call.out.push_back((*buf)->untyped_data());
    call.out_type.push_back((*buf)->element_type());
  }
  if (nsim < 0) return Fail("no field gives the batch size");
  if (nsim == 0) return ffi::Error::Success();
  if (nsim > std::numeric_limits<int>::max()) return Fail("batch too large");

  // small work runs on the calling thread: a hand-off to the pool costs more
  int nthread = static_cast<int>(threads);
  if (nsim * std::max<int64_t>(substeps, 1) * std::max(m->nv, static_cast<mjtSize>(1)) <
      serial_work) {
    nthread = 1;
  }
  PoolLease lease(e, nthread);
  Pool& pool = *lease;
  if (pool.nsim < nsim) {
    if (pool.batch) mjb_deleteBatch(pool.batch);
    mjBatchConfig config;
    mjb_defaultConfig(&config);
    config.nthread = nthread;
    config.persistent = 0;
    char error[512] = "";
    pool.batch = mjb_makeBatch(m, static_cast<int>(nsim), &config, error, sizeof(error));
    pool.nsim = pool.batch ? static_cast<int>(nsim) : 0;
    pool.expanded.clear();
    if (!pool.batch) return Fail(std::string("mjb_makeBatch failed: ") + error);
  }
  // per-simulation model fields: this call's params; fields an earlier call expanded
  // and this one does not give go back to the model's values
  for (const std::string& name : pool.expanded) {
    if (std::find(plan->params.begin(), plan->params.end(), name) != plan->params.end()) {
      continue;
    }
    auto* rows = static_cast<mjtNum*>(mjb_expand(pool.batch, name.c_str(), nullptr, nullptr));
    const std::vector<mjtNum>* found;
    {
      std::lock_guard<std::mutex> lock(e->mu);
      found = &e->defaults[name];  // std::map: the address stays valid
    }
    const std::vector<mjtNum>& value = *found;
    for (int64_t i = 0; i < nsim; ++i) {
      std::memcpy(rows + i * value.size(), value.data(), value.size() * sizeof(mjtNum));
    }
  }
  for (size_t k = 0; k < npar; ++k) {
    const std::string& name = plan->params[k];
    int size = 0, elem = 0;
    auto* rows = static_cast<mjtNum*>(mjb_expand(pool.batch, name.c_str(), &size, &elem));
    if (!rows || elem != static_cast<int>(sizeof(mjtNum))) {
      return Fail("params field '" + name + "' is not a floating-point mjModel field");
    }
    {
      std::lock_guard<std::mutex> lock(e->mu);
      if (!e->defaults.count(name)) {  // a fresh expansion holds the model's values
        e->defaults[name] = std::vector<mjtNum>(rows, rows + size);
      }
    }
    pool.expanded.insert(name);
    const ffi::AnyBuffer& buf = param_bufs[k];
    if (static_cast<int64_t>(buf.element_count()) != nsim * size) {
      return Fail("params field '" + name + "' does not have the model's shape per env");
    }
    Load(buf.untyped_data(), buf.element_type(), 0, rows, nsim * size);
  }

  std::vector<int> ids;
  const int* id_ptr = nullptr;
  if (pool.nsim != nsim) {
    ids.resize(nsim);
    for (int i = 0; i < nsim; ++i) ids[i] = i;
    id_ptr = ids.data();
  }
  mjb_apply(pool.batch, id_ptr, static_cast<int>(nsim), RunOne, &call, 0);
  const int* status = mjb_status(pool.batch);
  for (int i = 0; i < nsim; ++i) {
    if (status[i]) WriteNaN(call, i);
  }
  return ffi::Error::Success();
}

}  // namespace

// the only exported symbols (the library is built with hidden visibility)
#pragma GCC visibility push(default)

XLA_FFI_DEFINE_HANDLER_SYMBOL(JaxenvsMjStep, StepImpl,
                              ffi::Ffi::Bind()
                                  .Attr<std::string_view>("model")
                                  .Attr<int64_t>("substeps")
                                  .Attr<int64_t>("threads")
                                  .Attr<int64_t>("serial_work")
                                  .Attr<std::string_view>("inputs")
                                  .Attr<std::string_view>("params")
                                  .Attr<std::string_view>("outputs")
                                  .RemainingArgs()
                                  .RemainingRets());

extern "C" {

// Register a copy of model m under key (a digest of its content); 0 on success. Keys
// already registered are kept (the same digest is the same model).
int jaxenvs_register_model(const char* key, const mjModel* m, char* error, int error_sz) {
  std::lock_guard<std::mutex> lock(registry_mu);
  auto& registry = Registry();
  if (registry.count(key)) return 0;
  auto engine = std::make_unique<Engine>();
  engine->model = mj_copyModel(nullptr, m);
  if (!engine->model) {
    std::snprintf(error, error_sz, "mj_copyModel failed");
    return 1;
  }
  registry.emplace(key, std::move(engine));
  return 0;
}

#ifndef JAXENVS_BUILT_JAXLIB
#define JAXENVS_BUILT_JAXLIB "unknown"
#endif
#ifndef JAXENVS_BUILT_MUJOCO
#define JAXENVS_BUILT_MUJOCO "unknown"
#endif

// The jaxlib and mujoco package versions this library was built against: "jaxlib mujoco".
const char* jaxenvs_built_versions() { return JAXENVS_BUILT_JAXLIB " " JAXENVS_BUILT_MUJOCO; }

// mjcb_time as it is now, and set it (the Python side learns the bindings' default clock).
void* jaxenvs_clock() { return reinterpret_cast<void*>(mjcb_time); }
void jaxenvs_set_clock(void* clock) { mjcb_time = reinterpret_cast<mjfTime>(clock); }

// The bindings' default clock, which calls turn off (see QuietDefaultClock).
void jaxenvs_set_default_clock(void* clock) {
  default_clock.store(reinterpret_cast<mjfTime>(clock), std::memory_order_relaxed);
}

// MuJoCo's version this library was compiled against (mjVERSION_HEADER).
int jaxenvs_mujoco_header_version() { return mjVERSION_HEADER; }

// The version of the MuJoCo library loaded in this process (mj_version()).
int jaxenvs_mujoco_library_version() { return mj_version(); }

}  // extern "C"

#pragma GCC visibility pop
