// Simulator bindings. The model argument is the pinocchio.Model the user already
// has: Pinocchio's Python module registered its Boost.Python converter.
#include <boost/python.hpp>
#include <eigenpy/eigenpy.hpp>

#include <cmath>
#include <cstring>
#include <sstream>

#include "../sim/workspace.hpp"
#include "convert.hpp"
#include "expose.hpp"
#include "stiction/rk4_stability.hpp"
#include "stiction/rollout.hpp"
#include "stiction/simulator.hpp"
#include "stiction/step_derivatives.hpp"

namespace bp = boost::python;

namespace stiction {
namespace python {

template <>
IntegrationMode fromPython<IntegrationMode>(const bp::object& x, const std::string& name) {
  return toEnum<IntegrationMode>(x, name, "stiction.IntegrationMode");
}

template <>
ContactModel fromPython<ContactModel>(const bp::object& x, const std::string& name) {
  return toEnum<ContactModel>(x, name, "stiction.ContactModel");
}

namespace {

const pinocchio::Model& toModel(const bp::object& model) {
  return toObject<pinocchio::Model>(model, "SimulatorModel: model", "pinocchio.Model");
}

std::shared_ptr<SimulatorModel> makeSimulatorModel(const bp::object& model, const bp::object& halfspaces,
                                                   const bp::object& contacts, const bp::object& anchors,
                                                   const bp::object& settings, const bp::object& geometry,
                                                   const bp::object& pairs) {
  const pinocchio::Model& m = toModel(model);
  auto hs = toList<HalfSpace>(halfspaces, "SimulatorModel: halfspaces", "stiction.HalfSpace");
  auto cs = toList<SphereContact>(contacts, "SimulatorModel: contacts", "stiction.SphereContact");
  auto as = toList<PointAnchor>(anchors, "SimulatorModel: anchors", "stiction.PointAnchor");
  const SimulatorSettings& s = toObject<SimulatorSettings>(settings, "SimulatorModel: settings",
                                                           "stiction.SimulatorSettings");
  auto pair_list = toList<GeometryPairContact>(pairs, "SimulatorModel: pairs", "stiction.GeometryPairContact");
  if (geometry.is_none()) {
    if (!pair_list.empty()) throw std::invalid_argument("SimulatorModel: pairs need a geometry model");
    return std::make_shared<SimulatorModel>(m, std::move(hs), std::move(cs), std::move(as), s);
  }
  const auto& g = toObject<pinocchio::GeometryModel>(geometry, "SimulatorModel: geometry", "pinocchio.GeometryModel");
  return std::make_shared<SimulatorModel>(m, std::move(hs), std::move(cs), std::move(as), s, g, pair_list);
}

std::shared_ptr<SimulatorData> makeSimulatorData(const bp::object& sim) {
  return std::make_shared<SimulatorData>(toObject<SimulatorModel>(sim, "SimulatorData: sim", "stiction.SimulatorModel"));
}

// The arrays of a SimulatorData as Python sees them (docs/simulator.md):
// - the control inputs (kp, kd, q_target, v_target, tau_ff) are writable numpy views on the C++
//   vectors: `data.tau_ff[:] = u` reaches the next step. The vectors are sized once, when the data is
//   made, and every assignment copies into them, so their memory never moves; each view holds the
//   Python SimulatorData as its base, so the data outlives every view taken from it;
// - everything else (q, v, the outputs of the last step) is a read-only copy: the step reallocates
//   those vectors (integration, a new active set), so a view could dangle, and a write into a copy
//   would be silently lost; a read-only array makes it raise instead.
// Whole-array assignment goes through setChecked: a list of floats is accepted, None / str /
// complex raise TypeError, a wrong size or a NaN ValueError.
// A joint gain (kp, kd) below 0: ValueError naming the first such entry (the step refuses it too).
void checkGain(const double* x, Eigen::Index size, const char* name) {
  for (Eigen::Index i = 0; i < size; ++i)
    if (x[i] < 0.0) {
      std::ostringstream os;
      os << "SimulatorData." << name << "[" << i << "] is " << x[i] << ": a joint gain must be >= 0";
      throw std::invalid_argument(os.str());
    }
}

void setChecked(Eigen::VectorXd& dst, const bp::object& x, const char* name, bool gain = false) {
  // The common case first: a contiguous float64 numpy vector of the right size, copied without the
  // general conversion's temporaries (~0.2 us against ~3 us for Solo-12's tau_ff). memmove: x may be
  // a view of dst itself.
  if (PyArray_Check(x.ptr())) {
    auto* a = reinterpret_cast<PyArrayObject*>(x.ptr());
    if (PyArray_TYPE(a) == NPY_DOUBLE && PyArray_NDIM(a) == 1 && PyArray_DIM(a, 0) == dst.size() &&
        PyArray_ISCARRAY_RO(a) && PyArray_ISNOTSWAPPED(a)) {
      const Eigen::Map<const Eigen::VectorXd> v(static_cast<const double*>(PyArray_DATA(a)), dst.size());
      if (!v.allFinite())
        throw std::invalid_argument(std::string("SimulatorData.") + name + " has NaN or infinite entries");
      if (gain) checkGain(v.data(), v.size(), name);
      if (dst.size() > 0) std::memmove(dst.data(), v.data(), static_cast<std::size_t>(dst.size()) * sizeof(double));
      return;
    }
  }
  const Eigen::VectorXd v = toVector(x, std::string("SimulatorData.") + name, dst.size());
  if (!v.allFinite()) throw std::invalid_argument(std::string("SimulatorData.") + name + " has NaN or infinite entries");
  if (gain) checkGain(v.data(), v.size(), name);
  dst = v;  // a copy into dst's own memory (same size: no reallocation), never a move: views point into it
}

/// A writable float64 numpy vector over x's memory (no copy), its base `owner` (the Python object
/// holding the SimulatorData that x belongs to).
NdArray viewOf(const bp::object& owner, Eigen::VectorXd& x) {
  npy_intp size = static_cast<npy_intp>(x.size());
  PyObject* array = PyArray_New(&PyArray_Type, 1, &size, NPY_DOUBLE, nullptr, x.data(), 0, NPY_ARRAY_CARRAY, nullptr);
  if (array == nullptr) bp::throw_error_already_set();
  Py_INCREF(owner.ptr());
  if (PyArray_SetBaseObject(reinterpret_cast<PyArrayObject*>(array), owner.ptr()) != 0) {  // (steals owner)
    Py_DECREF(array);
    bp::throw_error_already_set();
  }
  return {bp::object(bp::handle<>(array))};
}

/// A read-only numpy copy of a matrix (eigenpy's conversion, its shapes unchanged).
template <typename Matrix>
NdArray readOnlyCopy(const Matrix& x) {
  bp::object array(x);
  PyArray_CLEARFLAGS(reinterpret_cast<PyArrayObject*>(array.ptr()), NPY_ARRAY_WRITEABLE);
  return {array};
}

/// The C++ data of a Python SimulatorData (reached only through its type's descriptors: a
/// descriptor checks the instance's type before calling).
SimulatorData& dataOf(PyObject* self) {
  return *static_cast<SimulatorData*>(
      bp::converter::get_lvalue_from_python(self, bp::converter::registered<SimulatorData>::converters));
}

/// A control input's attribute: its view (get) and a checked whole assignment (set), as a C-level
/// descriptor of the type (a getset, as a numpy or CPython attribute) rather than a Boost.Python
/// property, whose call dispatch cost ~0.04 us of each read or assignment (issue 25, Solo-12, best of
/// 15 x 20 000: reading the view 0.105 -> 0.066 us, assigning a float64 array 0.077 -> 0.039 us).
template <Eigen::VectorXd JointControl::*member>
struct ControlAttribute {
  static inline const char* name = nullptr;
  static inline bool gain = false;
  static PyObject* get(PyObject* self, void*) {
    try {
      return bp::incref(viewOf(bp::object(bp::borrowed(self)), dataOf(self).control.*member).array.ptr());
    } catch (...) {
      bp::handle_exception();
      return nullptr;
    }
  }
  static int set(PyObject* self, PyObject* value, void*) {
    if (value == nullptr) {
      PyErr_Format(PyExc_AttributeError, "SimulatorData.%s cannot be deleted", name);
      return -1;
    }
    try {
      setChecked(dataOf(self).control.*member, bp::object(bp::borrowed(value)), name, gain);
      return 0;
    } catch (...) {
      bp::handle_exception();  // (ValueError, TypeError: as the Boost.Python setter raised)
      return -1;
    }
  }
};

template <Eigen::VectorXd JointControl::*member>
void addControl(bp::class_<SimulatorData, std::shared_ptr<SimulatorData>, boost::noncopyable>& cls, const char* name,
                const char* doc) {
  using A = ControlAttribute<member>;
  A::name = name;
  A::gain = std::string(name) == "kp" || std::string(name) == "kd";
  static PyGetSetDef def = {name, &A::get, &A::set, doc, nullptr};  // (the type keeps a pointer to it)
  const bp::object descriptor{bp::handle<>(PyDescr_NewGetSet(reinterpret_cast<PyTypeObject*>(cls.ptr()), &def))};
  if (PyObject_SetAttrString(cls.ptr(), name, descriptor.ptr()) != 0) bp::throw_error_already_set();
}

NdArray get_q(const SimulatorData& d) { return readOnlyCopy(d.q); }
NdArray get_v(const SimulatorData& d) { return readOnlyCopy(d.v); }
// A new state starts a new trajectory: the blow-up check takes its reference again.
void set_q(SimulatorData& d, const bp::object& x) {
  setChecked(d.q, x, "q");
  d.reference_speed = -1.0;
}
void set_v(SimulatorData& d, const bp::object& x) {
  setChecked(d.v, x, "v");
  d.reference_speed = -1.0;
}
double get_t(const SimulatorData& d) { return d.t; }
void set_t(SimulatorData& d, const bp::object& x) {
  const double t = toDouble(x, "SimulatorData.t");
  if (!std::isfinite(t)) throw std::invalid_argument("SimulatorData.t must be finite");
  d.t = t;
  d.reference_speed = -1.0;
}

NdArray get_J(const SimulatorData& d) { return readOnlyCopy(denseJacobian(d)); }
NdArray get_A(const SimulatorData& d) { return readOnlyCopy(denseDelassus(d)); }
NdArray get_b(const SimulatorData& d) { return readOnlyCopy(d.out.b); }
NdArray get_drift(const SimulatorData& d) { return readOnlyCopy(d.out.drift); }
NdArray get_position_error(const SimulatorData& d) { return readOnlyCopy(d.out.position_error); }
NdArray get_gaps(const SimulatorData& d) { return readOnlyCopy(d.out.gaps); }
NdArray get_M(const SimulatorData& d) { return readOnlyCopy(denseMassMatrix(d)); }  // symmetric
NdArray get_tau(const SimulatorData& d) { return readOnlyCopy(d.out.tau); }
NdArray get_nle(const SimulatorData& d) { return readOnlyCopy(d.out.nle); }
NdArray get_actuator_torque(const SimulatorData& d) { return readOnlyCopy(d.out.actuator_torque); }
NdArray get_friction_torque(const SimulatorData& d) { return readOnlyCopy(d.out.friction_torque); }
NdArray get_limit_torque(const SimulatorData& d) { return readOnlyCopy(d.out.limit_torque); }
// The joint rows of the last problem: (kind, velocity coordinate) pairs, kind as its name.
bp::tuple get_joint_rows(const SimulatorData& d) {
  static const char* kNames[] = {"lower_limit", "upper_limit", "friction", "effort"};
  bp::list out;
  for (const JointRow& r : d.out.joint_rows) out.append(bp::make_tuple(kNames[static_cast<int>(r.kind)], r.dof));
  return bp::tuple(out);
}
NdArray get_candidate_lambda(const SimulatorData& d) { return readOnlyCopy(d.out.candidate_lambda); }
NdArray get_anchor_lambda(const SimulatorData& d) { return readOnlyCopy(d.out.anchor_lambda); }
NdArray get_candidate_velocity(const SimulatorData& d) { return readOnlyCopy(d.out.candidate_velocity); }
NdArray get_pair_points(const SimulatorData& d) { return readOnlyCopy(Eigen::MatrixXd(d.out.slot_point)); }
NdArray get_pair_normals(const SimulatorData& d) { return readOnlyCopy(Eigen::MatrixXd(d.out.slot_normal)); }
NdArray get_pair_t1(const SimulatorData& d) { return readOnlyCopy(Eigen::MatrixXd(d.out.slot_t1)); }
NdArray get_pair_t2(const SimulatorData& d) { return readOnlyCopy(Eigen::MatrixXd(d.out.slot_t2)); }
// The broad phase's pool (broad_phase.hpp): per held entry (pair index, first geometry, second geometry).
NdArray get_pool_pairs(const SimulatorData& d) {
  const auto& geoms = d.work->broad.geoms;
  int held = 0;
  for (const auto& g : geoms) held += g[0] >= 0;
  Eigen::MatrixXd out(held, 3);
  int r = 0;
  for (std::size_t p = 0; p < geoms.size(); ++p)
    if (geoms[p][0] >= 0) out.row(r++) << static_cast<double>(p), geoms[p][0], geoms[p][1];
  return readOnlyCopy(out);
}
// Sweep-and-prune over boxes given as 3 x n lower and upper corners: the overlapping pairs (a < b), k x 2.
NdArray sweepAndPruneOf(const bp::object& lower_in, const bp::object& upper_in) {
  const Eigen::MatrixXd lower = toMatrix(lower_in, "_sweep_and_prune: lower"),
                        upper = toMatrix(upper_in, "_sweep_and_prune: upper");
  if (lower.rows() != 3 || upper.rows() != 3 || lower.cols() != upper.cols())
    throw std::invalid_argument("_sweep_and_prune: lower and upper must both be 3 x n");
  std::vector<int> order;
  std::vector<std::pair<int, int>> pairs;
  sweepAndPrune(Eigen::Matrix3Xd(lower), Eigen::Matrix3Xd(upper), order, pairs, [](int, int) { return false; });
  Eigen::MatrixXd out(static_cast<Eigen::Index>(pairs.size()), 2);
  for (std::size_t k = 0; k < pairs.size(); ++k) out.row(static_cast<Eigen::Index>(k)) << pairs[k].first, pairs[k].second;
  return readOnlyCopy(out);
}
// Sensors of the last step (src/cpp/sim/sensors.cpp; Simulator.sensors() reads them)
NdArray get_contact_force(const SimulatorData& d) { return readOnlyCopy(Eigen::MatrixXd(d.out.contact_force)); }
NdArray get_accelerometer(const SimulatorData& d) { return readOnlyCopy(d.out.accelerometer); }
double get_sensor_time(const SimulatorData& d) { return d.out.sensor_time; }
// The last solve's result; its exact-law measures taken here (the step leaves them to whoever asks:
// a robot's step spent ~4 % of its time on them), of the problem it solved, still in d.work->problem.
SolverResult get_result(const SimulatorData& d) {
  completeLockedStep(d);  // (a step with its joints locked left its full problem to whoever asks)
  SolverResult r = d.out.result;
  if (!r.exact_law_measured && d.work->problem && r.lam.size() == d.work->problem->numRows() && r.u.size() == r.lam.size()) {
    measureExactLaw(*d.work->problem, r.lam, r.exact_law, kRelativeSpeedFloor, &r.u);
    r.exact_law_measured = true;
  }
  return r;
}
NdArray get_candidate_rows(const SimulatorData& d) {
  return readOnlyCopy(Eigen::VectorXi(
      Eigen::Map<const Eigen::VectorXi>(d.out.candidate_rows.data(), static_cast<Eigen::Index>(d.out.candidate_rows.size()))));
}
// Snapshots of the last step, immutable so that a write raises instead of being lost: tuples, and
// a read-only mapping for the timings.
bp::tuple get_active(const SimulatorData& d) { return bp::tuple(pyList(d.out.active)); }
bp::tuple get_states(const SimulatorData& d) { return bp::tuple(pyList(d.out.candidate_states)); }
ReadOnlyMapping get_timings(const SimulatorData& d) {
  bp::dict out;
  out["kinematics"] = d.out.timings.kinematics;
  out["delassus"] = d.out.timings.delassus;
  out["solve"] = d.out.timings.solve;
  out["integrate"] = d.out.timings.integrate;
  out["total"] = d.out.timings.total;
  return readOnlyMapping(out);
}

const SimulatorModel& simArg(const bp::object& x, const char* fn) {
  return toObject<SimulatorModel>(x, std::string(fn) + ": sim", "stiction.SimulatorModel");
}
SimulatorData& dataArg(const bp::object& x, const char* fn) {
  return toObject<SimulatorData>(x, std::string(fn) + ": data", "stiction.SimulatorData");
}

void doStep(const bp::object& sim, const bp::object& data) { step(simArg(sim, "step"), dataArg(data, "step")); }

/// step(sim, data) as a C function with the vectorcall convention: a Python loop of steps pays no
/// Boost.Python dispatch (its overload resolution and argument conversions: Solo-12's `sim.step()`
/// loop 5.25 -> 5.07 us a step, best of 7 x 2000). Arguments by position or by name, as the
/// Boost.Python function took them.
PyObject* fastStep(PyObject*, PyObject* const* args, Py_ssize_t nargs, PyObject* kwnames) {
  PyObject* given[2] = {nullptr, nullptr};
  static const char* const kNames[2] = {"sim", "data"};
  if (nargs > 2) {
    PyErr_Format(PyExc_TypeError, "step() takes 2 arguments (sim, data), %zd given", nargs);
    return nullptr;
  }
  for (Py_ssize_t i = 0; i < nargs; ++i) given[i] = args[i];
  const Py_ssize_t nkw = kwnames == nullptr ? 0 : PyTuple_GET_SIZE(kwnames);
  for (Py_ssize_t i = 0; i < nkw; ++i) {
    PyObject* key = PyTuple_GET_ITEM(kwnames, i);
    int slot = -1;
    for (int k = 0; k < 2; ++k)
      if (PyUnicode_CompareWithASCIIString(key, kNames[k]) == 0) slot = k;
    if (slot < 0 || given[slot] != nullptr) {
      PyErr_Format(PyExc_TypeError, slot < 0 ? "step() got an unexpected keyword argument '%U'"
                                             : "step() got multiple values for argument '%U'", key);
      return nullptr;
    }
    given[slot] = args[nargs + i];
  }
  for (int k = 0; k < 2; ++k)
    if (given[k] == nullptr) {
      PyErr_Format(PyExc_TypeError, "step() missing argument '%s'", kNames[k]);
      return nullptr;
    }
  try {
    doStep(bp::object(bp::borrowed(given[0])), bp::object(bp::borrowed(given[1])));
  } catch (...) {
    bp::handle_exception();
    return nullptr;
  }
  Py_RETURN_NONE;
}

void doBuild(const bp::object& sim_, const bp::object& data, const bp::object& q_, const bp::object& v_,
             const bp::object& delta_, const bp::object& zeta_, const bp::object& implicit_pd_step_) {
  const SimulatorModel& sim = simArg(sim_, "build_contact_problem");
  SimulatorData& d = dataArg(data, "build_contact_problem");
  const Eigen::VectorXd q = toVector(q_, "build_contact_problem: q", sim.model.nq);
  const Eigen::VectorXd v = toVector(v_, "build_contact_problem: v", sim.model.nv);
  const double delta = toDouble(delta_, "build_contact_problem: delta");
  const double zeta = toDouble(zeta_, "build_contact_problem: zeta");
  if (!(delta > 0.0) || !(zeta > 0.0)) throw std::invalid_argument("delta and zeta must be positive");
  const double pd_step = toDouble(implicit_pd_step_, "build_contact_problem: implicit_pd_step");
  if (!(pd_step >= 0.0) || !std::isfinite(pd_step))
    throw std::invalid_argument("build_contact_problem: implicit_pd_step must be finite and >= 0 (0: an explicit PD)");
  buildContactProblem(sim, d, q, v, delta, zeta, pd_step);
}

/// step_derivatives(sim, data, scratch): the analytic derivatives of the step from data's state, the
/// step run on scratch (stiction.derivatives.StepDerivatives reads the dict).
bp::dict stepDerivativesPy(const bp::object& sim_, const bp::object& data_, const bp::object& scratch_, bool wrt_q) {
  const SimulatorModel& sim = simArg(sim_, "step_derivatives");
  const SimulatorData& data = dataArg(data_, "step_derivatives");
  SimulatorData& scratch = dataArg(scratch_, "step_derivatives (scratch)");
  if (&scratch == &data) throw std::invalid_argument("step_derivatives: scratch must be another SimulatorData than data");
  StepDerivativesOutput d;
  stepDerivatives(sim, data, scratch, d, wrt_q);
  bp::dict out;
  out["dq_dq"] = d.dq_dq;
  out["dq_dv"] = d.dq_dv;
  out["dq_dtau"] = d.dq_dtau;
  out["dv_dq"] = d.dv_dq;
  out["dv_dv"] = d.dv_dv;
  out["dv_dtau"] = d.dv_dtau;
  out["dq_dmu"] = d.dq_dmu;
  out["dv_dmu"] = d.dv_dmu;
  out["has_q"] = d.has_q;
  out["q_next"] = d.q_next;
  out["v_next"] = d.v_next;
  bp::list modes, boundary, mu_indeterminate;
  static const char* const kModes[] = {"none", "open", "stick", "slide"};
  for (std::size_t i = 0; i < d.modes.size(); ++i) {
    modes.append(kModes[d.modes[i] + 1]);
    boundary.append(static_cast<bool>(d.boundary[i]));
    mu_indeterminate.append(static_cast<bool>(d.mu_indeterminate[i]));
  }
  out["modes"] = bp::tuple(modes);
  out["boundary"] = bp::tuple(boundary);
  out["mu_indeterminate"] = bp::tuple(mu_indeterminate);
  return out;
}

void translateNotImplemented(const DerivativesNotImplemented& e) { PyErr_SetString(PyExc_NotImplementedError, e.what()); }

/// The arrays of a recording laid out in `buffer` (a bytearray, Recording::allocate): numpy views
/// of its recorded rows, no copy.
bp::dict recordingViews(const Recording& rec, const bp::object& buffer) {
  const bp::object frombuffer = bp::import("numpy").attr("frombuffer");
  const long n = rec.records;
  bp::dict out;
  for (const Recording::Field& f : rec.fields()) {
    const long cols = f.cols < 0 ? 1 : static_cast<long>(f.cols);
    const bp::object array =
        frombuffer(buffer, "float64", n * cols, static_cast<long>(f.offset * sizeof(double)));
    out[f.name] = f.cols < 0 ? array : array.attr("reshape")(n, cols);
  }
  return out;
}

/// Run n steps in C++ (the GIL released), recording every `every`-th state (the first and the last too) into
/// the memory of the arrays returned: written once, not copied (the copy and the page faults of
/// its fresh memory were ~0.2 us of a 5.5 us robot step).
/// `before_step` (a callable, or None): called with no argument before each step, a controller in
/// the C++ loop (a Python loop calling one-step rollouts cost ~60 us a step of dicts and chunks).
/// The GIL is then held for the whole rollout, as by a Python loop of `step` (released at each step,
/// it had to be won back from any busy Python thread before each call: a switch interval, 5 ms);
/// Python threads still run meanwhile, in the callback's bytecode. What the callback raises stops
/// the rollout and propagates as raised, the data left after the steps done.
bp::dict rollout(const bp::object& sim_, const bp::object& data_, const bp::object& n_steps_,
                 const bp::object& every_, const bp::object& initial_contacts_, const bp::object& before_step_) {
  const SimulatorModel& sim = simArg(sim_, "rollout");
  SimulatorData& d = dataArg(data_, "rollout");
  const int n_steps = fromPython<int>(n_steps_, "rollout: n_steps");
  const int every = fromPython<int>(every_, "rollout: record_every");
  const bool initial_contacts = fromPython<bool>(initial_contacts_, "rollout: initial_contacts");
  PyObject* const callback = before_step_.is_none() ? nullptr : before_step_.ptr();
  if (callback != nullptr && PyCallable_Check(callback) == 0)
    raiseTypeError("rollout: before_step must be callable or None, got " + typeName(before_step_));
  Recording rec;
  bp::object buffer;
  if (n_steps >= 0 && every >= 1) {  // (else stiction::rollout says what is wrong)
    const std::size_t bytes = Recording::size(sim, n_steps, every) * sizeof(double);
    PyObject* block = PyByteArray_FromStringAndSize(nullptr, static_cast<Py_ssize_t>(bytes));
    if (block == nullptr) bp::throw_error_already_set();
    buffer = bp::object(bp::handle<>(block));
    rec.allocate(sim, n_steps, every, reinterpret_cast<double*>(PyByteArray_AsString(block)));
  }
  InUse busy(&d, "this SimulatorData");
  if (callback == nullptr) {
    ReleaseGil nogil;
    stiction::rollout(sim, d, n_steps, every, rec, initial_contacts);  // a failing step throws after the GIL is back
  } else {
    const auto call = [callback]() {
      PyObject* result = PyObject_CallNoArgs(callback);
      if (result == nullptr) bp::throw_error_already_set();  // (the Python error stays set: raised as it was)
      Py_DECREF(result);
    };
    stiction::rollout(sim, d, n_steps, every, rec, initial_contacts, call);
  }
  return recordingViews(rec, buffer);
}

/// Independent rollouts on a pool of C++ threads; a list of dicts (each with "error": None or
/// why that simulation stopped, its unrecorded rows dropped). Each recording is written into the
/// memory of the arrays returned (a bytearray per simulation, laid out and faulted in by the thread
/// that runs it), as rollout's: copying the recordings out after the threads had joined, with their
/// layout and NaN fill before the threads started, ran on one core (~20 % of an 8 x 2000-step
/// Solo-12 batch on one thread) and held 2 threads to 1.5x the throughput of one.
bp::list batchRollout(const bp::object& sims_, const bp::object& datas_, const bp::object& n_steps_,
                      const bp::object& every_, const bp::object& threads_) {
  const bp::list sims(sims_), datas(datas_);
  const long n = bp::len(sims);
  if (bp::len(datas) != n)
    throw std::invalid_argument("batch_rollout: " + std::to_string(n) + " models but " +
                                std::to_string(bp::len(datas)) + " data objects");
  const int n_steps = fromPython<int>(n_steps_, "batch_rollout: n_steps");
  const int every = fromPython<int>(every_, "batch_rollout: record_every");
  const int threads = fromPython<int>(threads_, "batch_rollout: threads");
  std::vector<BatchItem> items(n);
  std::vector<std::unique_ptr<InUse>> busy;
  for (long i = 0; i < n; ++i) {
    items[i].sim = &simArg(sims[i], "batch_rollout");
    items[i].data = &dataArg(datas[i], "batch_rollout");
    if (items[i].data->q.size() != items[i].sim->model.nq)
      throw std::invalid_argument("batch_rollout: item " + std::to_string(i) + ": its data was not made for its model");
  }
  // the blocks the recordings are laid out in: allocated here (the GIL held), not touched (their pages
  // are faulted in by the worker threads' NaN fill)
  std::vector<bp::object> buffers;
  std::vector<double*> storage;
  if (n_steps >= 0 && every >= 1) {  // (else stiction::batchRollout says what is wrong)
    for (long i = 0; i < n; ++i) {
      const std::size_t bytes = Recording::size(*items[i].sim, n_steps, every) * sizeof(double);
      PyObject* block = PyByteArray_FromStringAndSize(nullptr, static_cast<Py_ssize_t>(bytes));
      if (block == nullptr) bp::throw_error_already_set();
      buffers.emplace_back(bp::handle<>(block));
      storage.push_back(reinterpret_cast<double*>(PyByteArray_AsString(block)));
    }
  }
  std::vector<Recording> recs;
  {
    for (long i = 0; i < n; ++i) busy.push_back(std::make_unique<InUse>(items[i].data, "a SimulatorData of the batch"));
    ReleaseGil nogil;
    batchRollout(items, n_steps, every, threads, recs, storage);
  }
  bp::list out;
  for (std::size_t i = 0; i < recs.size(); ++i) {
    if (recs[i].fields().empty())  // (its layout failed in its thread: nothing recorded)
      throw std::runtime_error("batch_rollout: item " + std::to_string(i) + ": " + recs[i].error);
    bp::dict d = recordingViews(recs[i], buffers[i]);
    d["error"] = recs[i].error.empty() ? bp::object() : bp::object(recs[i].error);
    out.append(d);
  }
  return out;
}

int nq(const SimulatorModel& s) { return s.model.nq; }
int nv(const SimulatorModel& s) { return s.model.nv; }
long ncontacts(const SimulatorModel& s) { return static_cast<long>(s.contacts.size()); }
long ncandidates(const SimulatorModel& s) { return s.numCandidates(); }
long nanchors(const SimulatorModel& s) { return static_cast<long>(s.anchors.size()); }
bp::list halfspacesOf(const SimulatorModel& s) {
  return pyList(s.halfspaces);
}
bp::list contactsOf(const SimulatorModel& s) {
  return pyList(s.contacts);
}
SimulatorSettings settingsOf(const SimulatorModel& s) { return s.settings; }

}  // namespace

void exposeSimulator() {
  {
    bp::class_<HalfSpace> c("HalfSpace", "Free space {x : normal . x >= offset}; a ground or a wall.");
    checkedMember(c, "name", &HalfSpace::name);
    checkedMember(c, "normal", &HalfSpace::normal);
    checkedMember(c, "offset", &HalfSpace::offset);
    checkedMember(c, "frame", &HalfSpace::frame, "0: fixed in the world; else the body frame carrying it");
    c.add_property("tangent1", +[](const HalfSpace& h) -> Eigen::Vector3d { return h.tangent1; }, "completed by SimulatorModel");
    c.add_property("tangent2", +[](const HalfSpace& h) -> Eigen::Vector3d { return h.tangent2; });
  }
  {
    bp::class_<SphereContact> c("SphereContact", "A sphere (radius 0: a point) fixed in a frame, against a half-space.");
    checkedMember(c, "name", &SphereContact::name);
    checkedMember(c, "frame", &SphereContact::frame);
    checkedMember(c, "offset", &SphereContact::offset);
    checkedMember(c, "radius", &SphereContact::radius);
    checkedMember(c, "halfspace", &SphereContact::halfspace);
    checkedMember(c, "mu", &SphereContact::mu);
    checkedMember(c, "model", &SphereContact::model,
                  "ContactModel: spatial (t1, t2, n), planar (t1, n) or frictionless (n); mu = 0: 1 row");
    c.add_property(
        "planar", +[](const SphereContact& s) { return s.model == ContactModel::kPlanar; },
        +[](SphereContact& s, const bp::object& x) {
          s.model = fromPython<bool>(x, "SphereContact.planar") ? ContactModel::kPlanar : ContactModel::kSpatial;
        },
        "alias: model == ContactModel.planar (True sets planar, False spatial)");
  }
  {
    bp::class_<GeometryPairContact> c("GeometryPairContact",
                                      "A collision pair of the GeometryModel handled by coal (general shapes).");
    checkedMember(c, "name", &GeometryPairContact::name);
    checkedMember(c, "pair", &GeometryPairContact::pair, "index into GeometryModel.collisionPairs");
    checkedMember(c, "mu", &GeometryPairContact::mu);
    checkedMember(c, "max_contacts", &GeometryPairContact::max_contacts);
    checkedMember(c, "model", &GeometryPairContact::model, "ContactModel: spatial or frictionless; mu = 0: 1 row");
    checkedMember(c, "patch", &GeometryPairContact::patch,
                  "true: coal's contact patch (a manifold for flat faces, up to max_contacts vertices); "
                  "false: coal's contact points");
    checkedMember(c, "dynamic", &GeometryPairContact::dynamic,
                  "true: a pool entry (pair ignored): each step the broad phase gives it a pair of overlapping "
                  "shapes, kept while they overlap");
  }
  {
    bp::class_<PointAnchor> c("PointAnchor", "A frame point held at a world point: 3 bilateral rows.");
    checkedMember(c, "name", &PointAnchor::name);
    checkedMember(c, "frame", &PointAnchor::frame);
    checkedMember(c, "offset", &PointAnchor::offset);
    checkedMember(c, "target", &PointAnchor::target);
    checkedMember(c, "frame2", &PointAnchor::frame2, "0: hold at the world point target; else a frame");
    checkedMember(c, "offset2", &PointAnchor::offset2);
  }
  bp::enum_<ContactModel>("ContactModel")
      .value("spatial", ContactModel::kSpatial)
      .value("planar", ContactModel::kPlanar)
      .value("frictionless", ContactModel::kFrictionless);
  bp::enum_<IntegrationMode>("IntegrationMode")
      .value("timestep", IntegrationMode::kTimeStepping)
      .value("rk4", IntegrationMode::kRK4)
      .value("adaptive", IntegrationMode::kAdaptive);
  {
    bp::class_<SimulatorSettings> c("SimulatorSettings");
    checkedMember(c, "dt", &SimulatorSettings::dt,
                  "time step; RK4 needs dt <= its stability bound in delta and zeta (SimulatorModel says)");
    checkedMember(c, "mode", &SimulatorSettings::mode);
    checkedMember(c, "delta", &SimulatorSettings::delta, "ODE modes: Baumgarte delta (eq. 64); 0 = dt");
    checkedMember(c, "zeta", &SimulatorSettings::zeta, "ODE modes: Baumgarte zeta (eq. 64)");
    checkedMember(c, "ode_tolerance", &SimulatorSettings::ode_tolerance);
    checkedMember(c, "min_dt", &SimulatorSettings::min_dt);
    checkedMember(c, "activation_distance", &SimulatorSettings::activation_distance);
    checkedMember(c, "solver", &SimulatorSettings::solver);
    checkedMember(c, "formulation", &SimulatorSettings::formulation,
                  "exact (eq. 65), ccp, nakaoka, pyramid, penalty, pinocchio-admm, ... (formulation_infos())");
    checkedMember(c, "formulation_settings", &SimulatorSettings::formulation_settings,
                  "a copy: assign a whole FormulationSettings to change it");
    checkedMember(c, "warm_start", &SimulatorSettings::warm_start);
    checkedMember(c, "implicit_pd", &SimulatorSettings::implicit_pd,
                  "time stepping: joint PD implicit over the step (stable for any gains)");
    checkedMember(c, "joint_limits", &SimulatorSettings::joint_limits,
                  "1-dof joints' position limits (model.lowerPositionLimit, upperPositionLimit) as unilateral rows");
    checkedMember(c, "joint_friction", &SimulatorSettings::joint_friction,
                  "joints' dry friction (model.friction) as box rows |lambda| <= tau_c: exact stiction");
    checkedMember(c, "joint_damping", &SimulatorSettings::joint_damping,
                  "joints' viscous damping (model.damping), implicit in time stepping as the PD's damping");
    checkedMember(c, "effort_limits", &SimulatorSettings::effort_limits,
                  "actuator effort limits (0 < model.effortLimit < inf) on tau_ff + PD: box rows with the implicit PD");
    checkedMember(c, "joint_limit_margin", &SimulatorSettings::joint_limit_margin,
                  "rad or m: a position limit's row enters the problem within this distance (or when the "
                  "joint would reach it in a step)");
    checkedMember(c, "rigid_body_passes", &SimulatorSettings::rigid_body_passes,
                  "'fused' (default: one pass per robot, tree.cpp; a speed choice) or 'pinocchio' (Pinocchio's "
                  "forwardKinematics, crba, nonLinearEffects, Cholesky and integrate: the reference)");
    c.add_property(
        "tolerance", +[](const SimulatorSettings& s) { return s.solver_settings.tolerance; },
        +[](SimulatorSettings& s, const bp::object& x) {
          s.solver_settings.tolerance = toDouble(x, "SimulatorSettings.tolerance");
        });
    c.add_property(
        "max_iterations", +[](const SimulatorSettings& s) { return s.solver_settings.max_iterations; },
        +[](SimulatorSettings& s, const bp::object& x) {
          s.solver_settings.max_iterations = fromPython<int>(x, "SimulatorSettings.max_iterations");
        });
    c.add_property(
        "time_limit", +[](const SimulatorSettings& s) { return s.solver_settings.time_limit; },
        +[](SimulatorSettings& s, const bp::object& x) {
          s.solver_settings.time_limit = toDouble(x, "SimulatorSettings.time_limit");
        }, "per contact solve, seconds (0: none)");
  }
  bp::class_<SimulatorModel, std::shared_ptr<SimulatorModel>>(
      "SimulatorModel", "Immutable description: pinocchio.Model, half-spaces, contacts, anchors, settings.",
      bp::no_init)
      .def("__init__", bp::make_constructor(&makeSimulatorModel, bp::default_call_policies(),
                                            (bp::arg("model") = bp::object(), bp::arg("halfspaces") = bp::list(),
                                             bp::arg("contacts") = bp::list(), bp::arg("anchors") = bp::list(),
                                             bp::arg("settings") = SimulatorSettings(),
                                             bp::arg("geometry") = bp::object(), bp::arg("pairs") = bp::list())))
      .add_property("nq", &nq)
      .add_property("nv", &nv)
      .add_property("num_contacts", &ncontacts)
      .add_property("num_anchors", &nanchors)
      .add_property("num_candidates", &ncandidates, "sphere contacts + max_contacts slots per coal pair")
      .add_property("halfspaces", &halfspacesOf)
      .add_property("contacts", &contactsOf)
      .add_property("settings", &settingsOf);
  bp::class_<SimulatorData, std::shared_ptr<SimulatorData>, boost::noncopyable> data_class(
      "SimulatorData",
      "Per-step workspace and state of a SimulatorModel. The control inputs (kp, kd, q_target, v_target, "
      "tau_ff) read as writable numpy views on the data (in-place writes reach the next step); q, v and the "
      "outputs of the last step as read-only copies.",
      bp::no_init);
  addControl<&JointControl::kp>(data_class, "kp", "nv: joint stiffness (a view: in-place writes take effect)");
  addControl<&JointControl::kd>(data_class, "kd", "nv: joint damping (a view)");
  addControl<&JointControl::q_target>(data_class, "q_target", "nq: the PD's target configuration (a view)");
  addControl<&JointControl::v_target>(data_class, "v_target", "nv: the PD's target velocity (a view)");
  addControl<&JointControl::tau_ff>(data_class, "tau_ff", "nv: feed-forward generalized force (a view)");
  data_class
      .def("__init__", bp::make_constructor(&makeSimulatorData, bp::default_call_policies(),
                                            (bp::arg("sim") = bp::object())))
      .add_property("q", &get_q, &set_q, "nq: configuration (a read-only copy; assign a whole array to set it)")
      .add_property("v", &get_v, &set_v, "nv: velocity (a read-only copy; assign a whole array to set it)")
      .add_property("t", &get_t, &set_t)
      .add_property("J", &get_J)
      .add_property("A", &get_A)
      .add_property("b", &get_b)
      .add_property("drift", &get_drift)
      .add_property("position_error", &get_position_error)
      .add_property("gaps", &get_gaps)
      .add_property("M", &get_M)
      .add_property("tau", &get_tau)
      .add_property("nle", &get_nle, "C(q, v) v + g(q) at the last problem built")
      .add_property("actuator_torque", &get_actuator_torque,
                    "nv: the actuators' torque applied over the last step (tau_ff + PD, the implicit PD's at v+, "
                    "after the effort limit; docs/joint-rows.md)")
      .add_property("friction_torque", &get_friction_torque,
                    "nv: the joints' dry friction torque over the last step (0 where a joint has none)")
      .add_property("limit_torque", &get_limit_torque,
                    "nv: the joints' position-limit torque over the last step (0 where a joint had no limit row)")
      .add_property("joint_rows", &get_joint_rows,
                    "the joints' rows of the last problem, after the contacts and anchors: (kind, velocity "
                    "coordinate) with kind lower_limit, upper_limit, friction or effort (a tuple)")
      .add_property("active", &get_active, "indices of the candidates in the last problem (a tuple)")
      .add_property("candidate_lambda", &get_candidate_lambda)
      .add_property("anchor_lambda", &get_anchor_lambda)
      .add_property("contact_velocity", &get_candidate_velocity, "3 x candidates: J v after the step")
      .add_property("pair_points", &get_pair_points,
                    "3 x candidates: the world point of each coal pair slot at the last detection (sphere "
                    "contacts: 0)")
      .add_property("pair_normals", &get_pair_normals,
                    "3 x candidates: the normal of each coal pair slot, from the pair's first geometry to its "
                    "second (sphere contacts: 0)")
      .add_property("pair_t1", &get_pair_t1,
                    "3 x candidates: each coal pair slot's first tangent (rows t1, t2, n: the slot's lambda)")
      .add_property("pair_t2", &get_pair_t2, "3 x candidates: each coal pair slot's second tangent")
      .add_property("pool_pairs", &get_pool_pairs,
                    "k x 3: the dynamic pair entries held at the last detection (pair index, first geometry, "
                    "second geometry; stiction.pile)")
      .add_property("contact_force", &get_contact_force,
                    "3 x candidates: each candidate's force in the world frame after the last step, N (on the "
                    "contact's own body: the sphere's, a coal pair's second geometry's; 0 inactive)")
      .add_property("accelerometer", &get_accelerometer,
                    "3: the last step's proper acceleration R0^T (a - g) of the first root free flyer's origin, "
                    "in its frame (NaN without one or before a step)")
      .add_property("sensor_time", &get_sensor_time, "t when the last step's sensors were read (NaN: no step yet)")
      .add_property("states", &get_states, "per candidate: its ContactState at the last step (a tuple)")
      .add_property("rows", &get_candidate_rows, "per candidate: rows in the last problem (0: inactive)")
      .add_property("result", &get_result,
                    "the last solve's SolverResult: a snapshot (a copy at each read; its attributes and "
                    "arrays are read-only)")
      .add_property("timings", &get_timings,
                    "the last step's phase times in microseconds: kinematics, delassus, solve, integrate, "
                    "total (a read-only mapping)")
      .add_property("rhs_evaluations", +[](const SimulatorData& d) { return d.out.rhs_evaluations; })
      .add_property("last_dt", +[](const SimulatorData& d) { return d.out.last_dt; })
      .add_property("iterations_step", +[](const SimulatorData& d) { return d.out.iterations_step; })
      .add_property("max_residual_step", +[](const SimulatorData& d) { return d.out.max_residual_step; })
      .add_property("all_converged_step", +[](const SimulatorData& d) { return d.out.all_converged_step; })
      .add_property("sparse", +[](const SimulatorData& d) { return d.out.sparse; },
                    "True when the last problem's Delassus operator was assembled sparse (many parts, > 96 rows)")
      .add_property("parts", +[](const SimulatorData& d) { return static_cast<long>(d.work->parts.size()); },
                    "the number of parts of the world (subtrees of the universe, each its own Model and Data)");
  bp::def(
      "rk4_stable_step",
      +[](const bp::object& delta, const bp::object& zeta) {
        const double d = toDouble(delta, "rk4_stable_step: delta"), z = toDouble(zeta, "rk4_stable_step: zeta");
        if (!(d > 0.0) || !(z > 0.0)) throw std::invalid_argument("rk4_stable_step: delta and zeta must be positive");
        return rk4StableStep(d, z);
      },
      (bp::arg("delta"), bp::arg("zeta") = 0.5),
      "the largest dt SimulatorModel accepts in rk4 mode: 0.75 x RK4's stability limit on eq. 64");
  {
    // (the signature line in Boost.Python's form, for the stubs)
    static PyMethodDef def = {"step", reinterpret_cast<PyCFunction>(reinterpret_cast<void (*)()>(&fastStep)),
                              METH_FASTCALL | METH_KEYWORDS,
                              "step( (SimulatorModel)sim, (SimulatorData)data) -> None :\n    advance one step"};
    const bp::object module_name = bp::scope().attr("__name__");
    bp::scope().attr("step") = bp::object(bp::handle<>(PyCFunction_NewEx(&def, nullptr, module_name.ptr())));
  }
  bp::def(
      "contact_centers",
      +[](const bp::object& sim, const bp::object& Q) {
        return contactCenters(simArg(sim, "contact_centers"), toMatrix(Q, "contact_centers: Q"));
      },
      (bp::arg("sim"), bp::arg("Q")),
      "world position of every sphere contact's centre at each configuration (a row of Q): N x (3 contacts)");
  bp::def(
      "joint_placements",
      +[](const bp::object& sim, const bp::object& Q) {
        return jointPlacements(simArg(sim, "joint_placements"), toMatrix(Q, "joint_placements: Q"));
      },
      (bp::arg("sim"), bp::arg("Q")),
      "world placement of every joint at each configuration (a row of Q): N x (12 joints), per joint the "
      "rotation (column-major) then the translation");
  bp::def("_sweep_and_prune", &sweepAndPruneOf, (bp::arg("lower"), bp::arg("upper")),
          "the broad phase's sweep-and-prune (broad_phase.hpp) over boxes given by 3 x n lower and upper corners: "
          "the overlapping pairs (a < b) as a k x 2 array");
  bp::def("build_contact_problem", &doBuild,
          (bp::arg("sim"), bp::arg("data"), bp::arg("q"), bp::arg("v"), bp::arg("delta"), bp::arg("zeta"),
           bp::arg("implicit_pd_step") = 0.0),
          "fill data.J, A, b (eq. 27), drift, position_error and active at (q, v); implicit_pd_step = h > 0: the "
          "joint PD implicit over h, as a time step builds it (M's diagonal, the actuators' effort rows)");
  bp::register_exception_translator<DerivativesNotImplemented>(&translateNotImplemented);
  bp::def("step_derivatives", &stepDerivativesPy, (bp::arg("sim"), bp::arg("data"), bp::arg("scratch"), bp::arg("wrt_q") = true),
          "the analytic Jacobians of one time step from data's state (issue 26; the step is run on scratch, "
          "another SimulatorData of sim, data is not changed; wrt_q=False: dq_dq, dv_dq left NaN): a dict read by stiction.derivatives.StepDerivatives");
  bp::def("rollout", &rollout,
          (bp::arg("sim"), bp::arg("data"), bp::arg("n_steps"), bp::arg("record_every") = 1,
           bp::arg("initial_contacts") = true, bp::arg("before_step") = bp::object()),
          "n steps in C++ (the GIL released); returns a dict of arrays (t, q, v, lam, gaps, states, residual, ...); "
          "initial_contacts=False leaves record 0's contact fields as the last step wrote them (for a caller "
          "that drops record 0) instead of measuring them at the starting state; before_step: a callable run "
          "with no argument before each step (the GIL then held; what it raises stops the rollout and propagates)");
  bp::def("batch_rollout", &batchRollout,
          (bp::arg("sims"), bp::arg("datas"), bp::arg("n_steps"), bp::arg("record_every") = 1,
           bp::arg("threads") = 0),
          "independent rollouts of (sims[i], datas[i]) on a pool of C++ threads (0: one per core), the GIL "
          "released; a list of dicts as rollout's, each with 'error' (None, or why it stopped)");
}

}  // namespace python
}  // namespace stiction
