// Simulator bindings. The model argument is the pinocchio.Model the user already
// has: Pinocchio's Python module registered its Boost.Python converter.
#include <boost/python.hpp>
#include <eigenpy/eigenpy.hpp>

#include "expose.hpp"
#include "stiction/simulator.hpp"

namespace bp = boost::python;

namespace stiction {
namespace python {

namespace {

template <typename T>
std::vector<T> listOf(const bp::object& seq, const char* what) {
  std::vector<T> out;
  const long n = bp::len(seq);
  for (long i = 0; i < n; ++i) {
    bp::extract<T> e(seq[i]);
    if (!e.check()) throw std::invalid_argument(std::string(what) + "[" + std::to_string(i) + "] has the wrong type");
    out.push_back(e());
  }
  return out;
}

std::shared_ptr<SimulatorModel> makeSimulatorModel(const pinocchio::Model& model, const bp::object& halfspaces,
                                                   const bp::object& contacts, const bp::object& anchors,
                                                   const SimulatorSettings& settings, const bp::object& geometry,
                                                   const bp::object& pairs) {
  std::vector<GeometryPairContact> pair_list = listOf<GeometryPairContact>(pairs, "pairs");
  if (geometry.is_none()) {
    if (!pair_list.empty()) throw std::invalid_argument("pairs need a geometry model");
    return std::make_shared<SimulatorModel>(model, listOf<HalfSpace>(halfspaces, "halfspaces"),
                                            listOf<SphereContact>(contacts, "contacts"),
                                            listOf<PointAnchor>(anchors, "anchors"), settings);
  }
  bp::extract<const pinocchio::GeometryModel&> g(geometry);
  if (!g.check()) throw std::invalid_argument("geometry must be a pinocchio.GeometryModel");
  return std::make_shared<SimulatorModel>(model, listOf<HalfSpace>(halfspaces, "halfspaces"),
                                          listOf<SphereContact>(contacts, "contacts"),
                                          listOf<PointAnchor>(anchors, "anchors"), settings, g(), pair_list);
}

std::shared_ptr<SimulatorData> makeSimulatorData(const SimulatorModel& sim) {
  return std::make_shared<SimulatorData>(sim);
}

// Eigen members as numpy copies (get) and checked assignments (set).
#define STICTION_VECTOR_PROPERTY(Owner, member)                                         \
  Eigen::VectorXd get_##member(const Owner& o) { return o.member; }                    \
  void set_##member(Owner& o, const Eigen::VectorXd& x) {                              \
    if (x.size() != o.member.size())                                                   \
      throw std::invalid_argument(#member " needs " + std::to_string(o.member.size()) + \
                                  " entries, got " + std::to_string(x.size()));        \
    if (!x.allFinite()) throw std::invalid_argument(#member " has NaN or infinite entries"); \
    o.member = x;                                                                      \
  }

STICTION_VECTOR_PROPERTY(SimulatorData, q)
STICTION_VECTOR_PROPERTY(SimulatorData, v)
Eigen::VectorXd get_kp(const SimulatorData& d) { return d.control.kp; }
Eigen::VectorXd get_kd(const SimulatorData& d) { return d.control.kd; }
Eigen::VectorXd get_q_target(const SimulatorData& d) { return d.control.q_target; }
Eigen::VectorXd get_v_target(const SimulatorData& d) { return d.control.v_target; }
Eigen::VectorXd get_tau_ff(const SimulatorData& d) { return d.control.tau_ff; }
void setControlVector(Eigen::VectorXd& dst, const Eigen::VectorXd& x, const char* name) {
  if (x.size() != dst.size())
    throw std::invalid_argument(std::string(name) + " needs " + std::to_string(dst.size()) + " entries, got " +
                                std::to_string(x.size()));
  if (!x.allFinite()) throw std::invalid_argument(std::string(name) + " has NaN or infinite entries");
  dst = x;
}
void set_kp(SimulatorData& d, const Eigen::VectorXd& x) { setControlVector(d.control.kp, x, "kp"); }
void set_kd(SimulatorData& d, const Eigen::VectorXd& x) { setControlVector(d.control.kd, x, "kd"); }
void set_q_target(SimulatorData& d, const Eigen::VectorXd& x) { setControlVector(d.control.q_target, x, "q_target"); }
void set_v_target(SimulatorData& d, const Eigen::VectorXd& x) { setControlVector(d.control.v_target, x, "v_target"); }
void set_tau_ff(SimulatorData& d, const Eigen::VectorXd& x) { setControlVector(d.control.tau_ff, x, "tau_ff"); }

Eigen::MatrixXd get_J(const SimulatorData& d) { return d.J; }
Eigen::MatrixXd get_A(const SimulatorData& d) { return d.A; }
Eigen::VectorXd get_b(const SimulatorData& d) { return d.b; }
Eigen::VectorXd get_drift(const SimulatorData& d) { return d.drift; }
Eigen::VectorXd get_position_error(const SimulatorData& d) { return d.position_error; }
Eigen::VectorXd get_gaps(const SimulatorData& d) { return d.gaps; }
Eigen::MatrixXd get_M(const SimulatorData& d) {  // symmetric, from Pinocchio's upper part
  Eigen::MatrixXd M = d.data.M;
  M.triangularView<Eigen::StrictlyLower>() = M.transpose();
  return M;
}
Eigen::VectorXd get_tau(const SimulatorData& d) { return d.tau; }
Eigen::VectorXd get_nle(const SimulatorData& d) { return d.nle; }
Eigen::MatrixXd get_candidate_lambda(const SimulatorData& d) { return d.candidate_lambda; }
Eigen::MatrixXd get_anchor_lambda(const SimulatorData& d) { return d.anchor_lambda; }
Eigen::MatrixXd get_candidate_velocity(const SimulatorData& d) { return d.candidate_velocity; }
SolverResult get_result(const SimulatorData& d) { return d.result; }
bp::list get_active(const SimulatorData& d) {
  bp::list out;
  for (int i : d.active) out.append(i);
  return out;
}
bp::list get_states(const SimulatorData& d) {
  bp::list out;
  for (ContactState s : d.candidate_states) out.append(s);
  return out;
}
bp::dict get_timings(const SimulatorData& d) {
  bp::dict out;
  out["kinematics"] = d.timings.kinematics;
  out["delassus"] = d.timings.delassus;
  out["solve"] = d.timings.solve;
  out["integrate"] = d.timings.integrate;
  out["total"] = d.timings.total;
  return out;
}

void doStep(const SimulatorModel& sim, SimulatorData& d) { step(sim, d); }

void doBuild(const SimulatorModel& sim, SimulatorData& d, const Eigen::VectorXd& q, const Eigen::VectorXd& v,
             double delta, double zeta) {
  if (q.size() != sim.model.nq || v.size() != sim.model.nv)
    throw std::invalid_argument("build_contact_problem: q needs nq entries and v nv entries");
  if (!(delta > 0.0) || !(zeta > 0.0)) throw std::invalid_argument("delta and zeta must be positive");
  buildContactProblem(sim, d, q, v, delta, zeta);
}

/// Run n steps in C++, recording every `every`-th state (and the first).
bp::dict rollout(const SimulatorModel& sim, SimulatorData& d, int n_steps, int every) {
  if (n_steps < 0) throw std::invalid_argument("rollout: n_steps must be >= 0");
  if (every < 1) throw std::invalid_argument("rollout: record_every must be >= 1");
  const int records = n_steps / every + 1;
  const int nc = sim.numCandidates();
  const int na = static_cast<int>(sim.anchors.size());
  Eigen::VectorXd t(records), residual(records), iterations(records), converged(records), dts(records);
  Eigen::MatrixXd q(records, sim.model.nq), v(records, sim.model.nv), lam(records, 3 * nc), gaps(records, nc),
      states(records, nc), anchors(records, 3 * na), timings(records, 5), vel(records, 3 * nc);
  auto record = [&](int r) {
    t[r] = d.t;
    q.row(r) = d.q.transpose();
    v.row(r) = d.v.transpose();
    for (int i = 0; i < nc; ++i) {
      lam.block<1, 3>(r, 3 * i) = d.candidate_lambda.col(i).transpose();
      vel.block<1, 3>(r, 3 * i) = d.candidate_velocity.col(i).transpose();
      states(r, i) = static_cast<int>(d.candidate_states[i]);
    }
    gaps.row(r) = d.gaps.transpose();
    for (int a = 0; a < na; ++a) anchors.block<1, 3>(r, 3 * a) = d.anchor_lambda.col(a).transpose();
    residual[r] = d.max_residual_step;
    iterations[r] = d.iterations_step;
    converged[r] = d.all_converged_step ? 1.0 : 0.0;
    dts[r] = d.last_dt;
    timings.row(r) << d.timings.kinematics, d.timings.delassus, d.timings.solve, d.timings.integrate,
        d.timings.total;
  };
  record(0);
  int r = 1;
  for (int k = 1; k <= n_steps; ++k) {
    step(sim, d);
    if (k % every == 0) record(r++);
  }
  bp::dict out;
  out["t"] = t;
  out["q"] = q;
  out["v"] = v;
  out["lam"] = lam;
  out["contact_velocity"] = vel;
  out["gaps"] = gaps;
  out["states"] = states;
  out["anchor_lam"] = anchors;
  out["residual"] = residual;
  out["iterations"] = iterations;
  out["converged"] = converged;
  out["dt"] = dts;
  out["timings"] = timings;
  return out;
}

Eigen::Vector3d getNormal(const HalfSpace& h) { return h.normal; }
void setNormal(HalfSpace& h, const Eigen::Vector3d& n) { h.normal = n; }
Eigen::Vector3d getT1(const HalfSpace& h) { return h.tangent1; }
Eigen::Vector3d getT2(const HalfSpace& h) { return h.tangent2; }
Eigen::Vector3d getOffset(const SphereContact& c) { return c.offset; }
void setOffset(SphereContact& c, const Eigen::Vector3d& x) { c.offset = x; }
Eigen::Vector3d getAOffset(const PointAnchor& c) { return c.offset; }
void setAOffset(PointAnchor& c, const Eigen::Vector3d& x) { c.offset = x; }
Eigen::Vector3d getTarget(const PointAnchor& c) { return c.target; }
Eigen::Vector3d getAOffset2(const PointAnchor& c) { return c.offset2; }
void setAOffset2(PointAnchor& c, const Eigen::Vector3d& x) { c.offset2 = x; }
void setTarget(PointAnchor& c, const Eigen::Vector3d& x) { c.target = x; }
double getTol(const SimulatorSettings& s) { return s.solver_settings.tolerance; }
void setTol(SimulatorSettings& s, double x) { s.solver_settings.tolerance = x; }
int getMaxIt(const SimulatorSettings& s) { return s.solver_settings.max_iterations; }
void setMaxIt(SimulatorSettings& s, int x) { s.solver_settings.max_iterations = x; }
int nq(const SimulatorModel& s) { return s.model.nq; }
int nv(const SimulatorModel& s) { return s.model.nv; }
long ncontacts(const SimulatorModel& s) { return static_cast<long>(s.contacts.size()); }
long ncandidates(const SimulatorModel& s) { return s.numCandidates(); }
long nanchors(const SimulatorModel& s) { return static_cast<long>(s.anchors.size()); }
bp::list halfspacesOf(const SimulatorModel& s) {
  bp::list out;
  for (const auto& h : s.halfspaces) out.append(h);
  return out;
}
bp::list contactsOf(const SimulatorModel& s) {
  bp::list out;
  for (const auto& c : s.contacts) out.append(c);
  return out;
}
SimulatorSettings settingsOf(const SimulatorModel& s) { return s.settings; }

}  // namespace

void exposeSimulator() {
  bp::class_<HalfSpace>("HalfSpace", "Free space {x : normal . x >= offset}; a ground or a wall.")
      .def_readwrite("name", &HalfSpace::name)
      .add_property("normal", &getNormal, &setNormal)
      .def_readwrite("offset", &HalfSpace::offset)
      .def_readwrite("frame", &HalfSpace::frame, "0: fixed in the world; else the body frame carrying it")
      .add_property("tangent1", &getT1, "completed by SimulatorModel")
      .add_property("tangent2", &getT2);
  bp::class_<SphereContact>("SphereContact",
                            "A sphere (radius 0: a point) fixed in a frame, against a half-space.")
      .def_readwrite("name", &SphereContact::name)
      .def_readwrite("frame", &SphereContact::frame)
      .add_property("offset", &getOffset, &setOffset)
      .def_readwrite("radius", &SphereContact::radius)
      .def_readwrite("halfspace", &SphereContact::halfspace)
      .def_readwrite("mu", &SphereContact::mu)
      .def_readwrite("planar", &SphereContact::planar, "2 rows (t1, n) instead of 3");
  bp::class_<GeometryPairContact>("GeometryPairContact",
                                  "A collision pair of the GeometryModel handled by coal (general shapes).")
      .def_readwrite("name", &GeometryPairContact::name)
      .def_readwrite("pair", &GeometryPairContact::pair, "index into GeometryModel.collisionPairs")
      .def_readwrite("mu", &GeometryPairContact::mu)
      .def_readwrite("max_contacts", &GeometryPairContact::max_contacts);
  bp::class_<PointAnchor>("PointAnchor", "A frame point held at a world point: 3 bilateral rows.")
      .def_readwrite("name", &PointAnchor::name)
      .def_readwrite("frame", &PointAnchor::frame)
      .add_property("offset", &getAOffset, &setAOffset)
      .add_property("target", &getTarget, &setTarget)
      .def_readwrite("frame2", &PointAnchor::frame2, "0: hold at the world point target; else a frame")
      .add_property("offset2", &getAOffset2, &setAOffset2);
  bp::enum_<IntegrationMode>("IntegrationMode")
      .value("timestep", IntegrationMode::kTimeStepping)
      .value("rk4", IntegrationMode::kRK4)
      .value("adaptive", IntegrationMode::kAdaptive);
  bp::class_<SimulatorSettings>("SimulatorSettings")
      .def_readwrite("dt", &SimulatorSettings::dt)
      .def_readwrite("mode", &SimulatorSettings::mode)
      .def_readwrite("delta", &SimulatorSettings::delta, "ODE modes: Baumgarte delta (eq. 64); 0 = dt")
      .def_readwrite("zeta", &SimulatorSettings::zeta, "ODE modes: Baumgarte zeta (eq. 64)")
      .def_readwrite("ode_tolerance", &SimulatorSettings::ode_tolerance)
      .def_readwrite("min_dt", &SimulatorSettings::min_dt)
      .def_readwrite("activation_distance", &SimulatorSettings::activation_distance)
      .def_readwrite("solver", &SimulatorSettings::solver)
      .def_readwrite("warm_start", &SimulatorSettings::warm_start)
      .def_readwrite("implicit_pd", &SimulatorSettings::implicit_pd,
                     "time stepping: joint PD implicit over the step (stable for any gains)")
      .add_property("tolerance", &getTol, &setTol)
      .add_property("max_iterations", &getMaxIt, &setMaxIt);
  bp::class_<SimulatorModel, std::shared_ptr<SimulatorModel>>(
      "SimulatorModel", "Immutable description: pinocchio.Model, half-spaces, contacts, anchors, settings.",
      bp::no_init)
      .def("__init__", bp::make_constructor(&makeSimulatorModel, bp::default_call_policies(),
                                            (bp::arg("model"), bp::arg("halfspaces"), bp::arg("contacts"),
                                             bp::arg("anchors"), bp::arg("settings"),
                                             bp::arg("geometry") = bp::object(), bp::arg("pairs") = bp::list())))
      .add_property("nq", &nq)
      .add_property("nv", &nv)
      .add_property("num_contacts", &ncontacts)
      .add_property("num_anchors", &nanchors)
      .add_property("num_candidates", &ncandidates, "sphere contacts + max_contacts slots per coal pair")
      .add_property("halfspaces", &halfspacesOf)
      .add_property("contacts", &contactsOf)
      .add_property("settings", &settingsOf);
  bp::class_<SimulatorData, std::shared_ptr<SimulatorData>, boost::noncopyable>(
      "SimulatorData", "Per-step workspace and state of a SimulatorModel.", bp::no_init)
      .def("__init__", bp::make_constructor(&makeSimulatorData))
      .add_property("q", &get_q, &set_q)
      .add_property("v", &get_v, &set_v)
      .def_readwrite("t", &SimulatorData::t)
      .add_property("kp", &get_kp, &set_kp)
      .add_property("kd", &get_kd, &set_kd)
      .add_property("q_target", &get_q_target, &set_q_target)
      .add_property("v_target", &get_v_target, &set_v_target)
      .add_property("tau_ff", &get_tau_ff, &set_tau_ff)
      .add_property("J", &get_J)
      .add_property("A", &get_A)
      .add_property("b", &get_b)
      .add_property("drift", &get_drift)
      .add_property("position_error", &get_position_error)
      .add_property("gaps", &get_gaps)
      .add_property("M", &get_M)
      .add_property("tau", &get_tau)
      .add_property("nle", &get_nle, "C(q, v) v + g(q) at the last problem built")
      .add_property("active", &get_active)
      .add_property("candidate_lambda", &get_candidate_lambda)
      .add_property("anchor_lambda", &get_anchor_lambda)
      .add_property("contact_velocity", &get_candidate_velocity, "3 x candidates: J v after the step")
      .add_property("states", &get_states)
      .add_property("result", &get_result)
      .add_property("timings", &get_timings)
      .def_readonly("rhs_evaluations", &SimulatorData::rhs_evaluations)
      .def_readonly("last_dt", &SimulatorData::last_dt)
      .def_readonly("iterations_step", &SimulatorData::iterations_step)
      .def_readonly("max_residual_step", &SimulatorData::max_residual_step)
      .def_readonly("all_converged_step", &SimulatorData::all_converged_step);
  bp::def("step", &doStep, (bp::arg("sim"), bp::arg("data")), "advance one step");
  bp::def("build_contact_problem", &doBuild,
          (bp::arg("sim"), bp::arg("data"), bp::arg("q"), bp::arg("v"), bp::arg("delta"), bp::arg("zeta")),
          "fill data.J, A, b (eq. 27), drift, position_error and active at (q, v)");
  bp::def("rollout", &rollout, (bp::arg("sim"), bp::arg("data"), bp::arg("n_steps"), bp::arg("record_every") = 1),
          "n steps in C++; returns a dict of arrays (t, q, v, lam, gaps, states, residual, ...)");
}

}  // namespace python
}  // namespace stiction
