// MuJoCo's C engine as an XLA FFI custom call (CPU): jaxenvs' native engine.
//
// One call steps a batch of simulations of one registered model, each from its own full
// input state, and writes the fields it asks for. Python (jaxenvs/physics/cengine.py) builds the
// call; this file holds no Python.
//
// Contract of the FFI target "jaxenvs_mj_step":
//   attributes  model    the key a model was registered under (jaxenvs_register_model)
//               substeps mj_step calls with the controls held; 0: one mj_forward
//               threads  the most threads that step the batch: the caller's and tasks
//                        on XLA's intra-op thread pool (the call starts no thread)
//               serial_work  below this many (sims x substeps x dofs) one thread steps all
//               inputs   comma-separated mjData fields read, in argument order ("time",
//                        "qpos", ...: the state a step reads)
//               params   comma-separated mjModel fields given per simulation, after inputs
//               outputs  comma-separated mjData fields written, in result order;
//                        "actuator_moment" is written dense (nu x nv), as MJX holds it
//   arguments   one buffer per input then per param, each (batch..., field size) with the
//               same leading batch dims; float32 or float64 (eq_active: bool)
//   results     one buffer per output, (batch..., field size), float32 or float64
// Every simulation is stepped on its own, from its own inputs and model fields, in an
// mjData of one of MuJoCo's one-thread batches (mjBatch, which traps MuJoCo's errors), a
// range of simulations after another; so results are the same bit for bit at any thread
// count. Derived outputs are zeroed before the step, so a field this step does not
// compute is 0 (as in a fresh mjx.Data), never another simulation's value. A simulation
// that raised a bad-state warning (MuJoCo resets such a state and carries on) or an error
// comes back with every output NaN but time, which advances as the step would have.

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
#include <string>
#include <string_view>
#include <thread>
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

struct ModelField {
  int64_t offset = -1;  // of the pointer member in mjModel; -1: no such array
  int64_t size = 0;     // elements
  bool is_num = false;  // mjtNum
};

struct Plan {
  std::vector<Slot> inputs, outputs;
  std::vector<std::string> params;
  std::vector<ModelField> param_fields;  // where each params field is in mjModel
  std::vector<const DataField*> zeroed;  // derived outputs, cleared before a step
  int input_spec = 0;                    // the mjtState components the inputs set
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

// the state fields a step reads, each with the mjtState component it is
const std::map<std::string, int>& StateFields() {
  static const auto* fields = new std::map<std::string, int>{
      {"time", mjSTATE_TIME},
      {"qpos", mjSTATE_QPOS},
      {"qvel", mjSTATE_QVEL},
      {"act", mjSTATE_ACT},
      {"qacc_warmstart", mjSTATE_WARMSTART},
      {"ctrl", mjSTATE_CTRL},
      {"qfrc_applied", mjSTATE_QFRC_APPLIED},
      {"xfrc_applied", mjSTATE_XFRC_APPLIED},
      {"eq_active", mjSTATE_EQ_ACTIVE},
      {"mocap_pos", mjSTATE_MOCAP_POS},
      {"mocap_quat", mjSTATE_MOCAP_QUAT},
      {"userdata", mjSTATE_USERDATA}};
  return *fields;
}

// The array of model m called name: its pointer's offset in mjModel, and its size.
ModelField FindModelField(const mjModel* m, std::string_view name) {
  MJMODEL_POINTERS_PREAMBLE(m)
#define X(type, field, nr, nc)                                                  \
  if (name == #field) {                                                         \
    return ModelField{static_cast<int64_t>(offsetof(mjModel, field)),           \
                      static_cast<int64_t>(m->nr) * static_cast<int64_t>(nc),   \
                      std::is_same<type, mjtNum>::value};                       \
  }
#define XNV X
  MJMODEL_POINTERS
#undef XNV
#undef X
  return ModelField{};
}

mjtNum* ModelArray(const mjModel* m, int64_t offset) {
  return *reinterpret_cast<mjtNum* const*>(reinterpret_cast<const char*>(m) + offset);
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

// One simulation's MuJoCo batch (one thread: the caller's), which steps a range of a
// call's envs one after another in its mjData (RunRange). MuJoCo's batch loads a state
// (mj_setState) and sets its error trap once per range, not once per env.
struct Sim {
  mjBatch* batch = nullptr;
  // per-env model fields this batch's model holds values of (offset -> size), put back to
  // the model's values when a call does not give them
  std::map<int64_t, int64_t> written;
};

struct Engine {
  mjModel* model = nullptr;
  // guards the members below; a range holds it only to look up a plan or take a Sim, so
  // ranges of one call, and calls from several devices, step on Sims of their own
  std::mutex mu;
  std::vector<std::unique_ptr<Sim>> idle;  // free Sims
  std::map<std::string, Plan> plans;
  ~Engine() {
    for (auto& sim : idle) {
      if (sim->batch) mjb_deleteBatch(sim->batch);
    }
    if (model) mj_deleteModel(model);
  }
};

// A Sim for one range, given back to the engine when the range is done.
class SimLease {
 public:
  explicit SimLease(Engine* e) : e_(e) {
    std::lock_guard<std::mutex> lock(e->mu);
    if (e->idle.empty()) {
      sim_ = std::make_unique<Sim>();
    } else {
      sim_ = std::move(e->idle.back());
      e->idle.pop_back();
    }
  }
  ~SimLease() {
    std::lock_guard<std::mutex> lock(e_->mu);
    e_->idle.push_back(std::move(sim_));
  }
  Sim& operator*() { return *sim_; }

 private:
  Engine* e_;
  std::unique_ptr<Sim> sim_;
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
    plan.input_spec |= StateFields().at(name);
    plan.inputs.push_back(*s);
  }
  for (const std::string& name : Split(outputs)) {
    auto s = slot(name, false);
    if (s.has_error()) return ffi::Unexpected(s.error());
    if (s->kind != Kind::kTime && !StateFields().count(name)) plan.zeroed.push_back(s->field);
    plan.outputs.push_back(*s);
  }
  plan.params = Split(params);
  for (const std::string& name : plan.params) {
    ModelField f = FindModelField(m, name);
    if (f.offset < 0 || !f.is_num) {
      return ffi::Unexpected(
          Fail("params field '" + name + "' is not a floating-point mjModel field"));
    }
    plan.param_fields.push_back(f);
  }
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

struct ParamSlot {  // one per-env model field of a call
  int64_t offset;    // of its pointer in mjModel (FindModelField)
  int64_t size;      // values per env
  const void* src;   // (envs, size)
  ffi::DataType type;
};

struct CallArgs {
  Engine* engine;
  const Plan* plan;
  int substeps;
  double timestep;  // the model's
  std::vector<const void*> in;
  std::vector<ffi::DataType> in_type;
  std::vector<void*> out;
  std::vector<ffi::DataType> out_type;
  std::vector<ParamSlot> params;
  int restore = 0;  // mjtState components put back before each env (Range::snapshot)
};

// warnings that mean a step went wrong; MuJoCo resets a bad state (zeroing every counter)
// and carries on
constexpr int kBadWarnings[] = {mjWARN_CONTACTFULL, mjWARN_CNSTRFULL, mjWARN_BADQPOS,
                                mjWARN_BADQVEL, mjWARN_BADQACC, mjWARN_BADCTRL};

// A failed step's outputs: every field NaN but time, which advances as a step would have.
void WriteNaN(const CallArgs& a, int64_t sim) {
  double time = 0;
  for (size_t k = 0; k < a.plan->inputs.size(); ++k) {
    if (a.plan->inputs[k].kind == Kind::kTime) Load(a.in[k], a.in_type[k], sim, &time, 1);
  }
  time += a.substeps * a.timestep;
  for (size_t k = 0; k < a.plan->outputs.size(); ++k) {
    const Slot& s = a.plan->outputs[k];
    if (s.kind == Kind::kTime) {
      Store(&time, a.out[k], a.out_type[k], sim, 1);
    } else {
      StoreNaN(a.out[k], a.out_type[k], sim * s.size, s.size);
    }
  }
}

// Step env sim in d, from its inputs, and write its outputs.
void RunOne(const mjModel* m, mjData* d, int64_t sim, const CallArgs& a) {
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
  if (a.substeps == 0) {
    mj_forward(m, d);
  } else {
    for (int i = 0; i < a.substeps; ++i) mj_step(m, d);
  }
  bool bad = false;  // a warning raised (counter above 1) or a reset (counters zeroed)
  for (int w : kBadWarnings) bad |= d->warning[w].number != 1;
  if (bad) {
    WriteNaN(a, sim);
    return;
  }
  for (size_t k = 0; k < plan.outputs.size(); ++k) {
    const Slot& s = plan.outputs[k];
    if (s.kind == Kind::kTime) {
      Store(&d->time, a.out[k], a.out_type[k], sim, 1);
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

// ------------------------------------------------------------------ ranges of envs

// ranges a worker thread's share of a call is cut into, so that threads whose envs step
// faster take over the ranges of slower ones (a walker's contacts vary), each of at least
// kMinRange envs (a range costs one mjb_apply: a state load and an error trap)
constexpr int64_t kRangesPerWorker = 16;
constexpr int64_t kMinRange = 8;

struct alignas(64) Range {  // envs [begin, end) of a call, stepped in turn in one mjData
  // the env being stepped, or the next: where an error stopped (atomic: stored before
  // each step, for the caller of mjb_apply to read after an error left RunRange)
  std::atomic<int64_t> begin{0};
  int64_t end = 0;
  std::vector<mjtNum> snapshot;  // the state components no input sets (CallArgs::restore)
  Sim* sim = nullptr;
  const CallArgs* call = nullptr;
};

// Step range's envs one after another in d (an mjfBatchFunc; arg: the Range). Each env's
// per-env model fields are written into m, its Sim's own model, first. Nothing here
// needs a destructor: an error in a step leaves this function without unwinding it.
void RunRange(const mjModel* m, mjData* d, int, void* arg) {
  Range& range = *static_cast<Range*>(arg);
  const CallArgs& a = *range.call;
  const mjModel* base = a.engine->model;
  for (auto it = range.sim->written.begin(); it != range.sim->written.end();) {
    bool given = std::any_of(a.params.begin(), a.params.end(),
                             [&](const ParamSlot& p) { return p.offset == it->first; });
    if (given) {
      ++it;
      continue;
    }
    std::memcpy(ModelArray(m, it->first), ModelArray(base, it->first),
                it->second * sizeof(mjtNum));
    it = range.sim->written.erase(it);
  }
  for (const ParamSlot& p : a.params) range.sim->written[p.offset] = p.size;
  if (a.restore) mj_getState(m, d, range.snapshot.data(), a.restore);
  for (;;) {
    int64_t i = range.begin.load(std::memory_order_relaxed);
    if (i >= range.end) break;
    if (a.restore) mj_setState(m, d, range.snapshot.data(), a.restore);
    for (const ParamSlot& p : a.params) {
      Load(p.src, p.type, i * p.size, ModelArray(m, p.offset), p.size);
    }
    RunOne(m, d, i, a);
    range.begin.store(i + 1, std::memory_order_relaxed);
  }
}

// One call's envs cut into ranges, shared by the threads that step them: the caller's
// and the tasks it hands to XLA's thread pool. Held by a shared_ptr, so that a task
// which starts after the call returned finds nothing left and touches no buffer.
struct Work {
  CallArgs call;
  std::vector<Range> ranges;
  std::atomic<size_t> next{0};  // the next range to claim
  std::atomic<size_t> done{0};  // ranges stepped
  std::mutex mu;
  std::string error;  // the first range that could not run, and why
};

// Step range r on a Sim of its own. An env whose step raised an error ends mjb_apply
// early: it comes back NaN, and the rest of the range is stepped again.
void StepRange(Work& w, Range& range) {
  Engine* e = w.call.engine;
  SimLease lease(e);
  Sim& sim = *lease;
  if (!sim.batch) {
    mjBatchConfig config;
    mjb_defaultConfig(&config);
    config.nthread = 1;
    config.persistent = 0;
    char error[512] = "";
    sim.batch = mjb_makeBatch(e->model, 1, &config, error, sizeof(error));
    if (!sim.batch) {
      std::lock_guard<std::mutex> lock(w.mu);
      if (w.error.empty()) w.error = std::string("mjb_makeBatch failed: ") + error;
      return;
    }
  }
  range.sim = &sim;
  while (range.begin.load(std::memory_order_relaxed) < range.end) {
    mjb_apply(sim.batch, nullptr, 1, RunRange, &range, 0);
    if (mjb_status(sim.batch)[0]) {
      int64_t failed = range.begin.load(std::memory_order_relaxed);
      WriteNaN(w.call, failed);
      range.begin.store(failed + 1, std::memory_order_relaxed);
    }
  }
}

// Claim and step ranges until none is left.
void Drain(Work& w) {
  for (;;) {
    size_t r = w.next.fetch_add(1, std::memory_order_relaxed);
    if (r >= w.ranges.size()) return;
    StepRange(w, w.ranges[r]);
    w.done.fetch_add(1, std::memory_order_release);
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

ffi::Error StepImpl(ffi::ThreadPool pool, std::string_view model_key, int64_t substeps,
                    int64_t threads, int64_t serial_work, std::string_view inputs,
                    std::string_view params, std::string_view outputs,
                    ffi::RemainingArgs args, ffi::RemainingRets rets) {
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

  auto work = std::make_shared<Work>();
  CallArgs& call = work->call;
  call.engine = e;
  call.plan = plan;
  call.substeps = static_cast<int>(substeps);
  call.timestep = m->opt.timestep;
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

  for (size_t k = 0; k < npar; ++k) {
    const ModelField& f = plan->param_fields[k];
    const ffi::AnyBuffer& buf = param_bufs[k];
    if (static_cast<int64_t>(buf.element_count()) != nsim * f.size) {
      return Fail("params field '" + plan->params[k] +
                  "' does not have the model's shape per env");
    }
    call.params.push_back(ParamSlot{f.offset, f.size, buf.untyped_data(), buf.element_type()});
  }
  // the state a range's mjData holds that no input sets (a zero-sized input's component,
  // ...) goes back to the batch's initial state before each env, as mj_setState would
  call.restore = mjSTATE_INTEGRATION & ~plan->input_spec;
  for (int bit = 1; bit <= call.restore; bit <<= 1) {
    if ((call.restore & bit) && mj_stateSize(m, bit) == 0) call.restore &= ~bit;
  }

  // Up to `threads` threads step the envs: this one and tasks on XLA's own thread pool
  // (so no thread of ours competes with XLA's for the cores), a few ranges each to even
  // out envs that step slower than others. Small work stays on this thread: a hand-off
  // costs more.
  int64_t workers = std::min<int64_t>(threads, pool.num_threads() + 1);
  if (nsim * std::max<int64_t>(substeps, 1) * std::max(m->nv, static_cast<mjtSize>(1)) <
      serial_work) {
    workers = 1;
  }
  int64_t nrange = std::max<int64_t>(
      1, std::min<int64_t>((nsim + kMinRange - 1) / kMinRange, workers * kRangesPerWorker));
  workers = std::min(workers, nrange);
  int64_t snapshot = call.restore ? mj_stateSize(m, call.restore) : 0;
  work->ranges = std::vector<Range>(nrange);
  for (int64_t r = 0; r < nrange; ++r) {
    Range& range = work->ranges[r];
    range.begin.store(r * nsim / nrange, std::memory_order_relaxed);
    range.end = (r + 1) * nsim / nrange;
    range.snapshot.resize(snapshot);
    range.call = &work->call;
  }
  for (int64_t k = 1; k < workers; ++k) pool.Schedule([work] { Drain(*work); });
  Drain(*work);
  // ranges other threads claimed are being stepped: wait for them
  while (work->done.load(std::memory_order_acquire) < work->ranges.size()) {
    std::this_thread::yield();
  }
  if (!work->error.empty()) return Fail(work->error);
  return ffi::Error::Success();
}

}  // namespace

// the only exported symbols (the library is built with hidden visibility)
#pragma GCC visibility push(default)

XLA_FFI_DEFINE_HANDLER_SYMBOL(JaxenvsMjStep, StepImpl,
                              ffi::Ffi::Bind()
                                  .Ctx<ffi::ThreadPool>()
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
