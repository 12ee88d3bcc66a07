// Sensors (docs/simulator.md, "Sensors"): what a robot's instruments would read after a step,
// from what the step already computed.
//
//   contact force   each candidate's force in the world frame: the last solve's (t1, t2, n)
//                   components (time stepping: the impulse P / h, eq. 70) turned by the frame its
//                   problem was built in. The frames are read here, at the step's end, because a
//                   moving half-space's (and a coal slot's) frame changes from step to step and is
//                   only known at detection.
//   accelerometer   the proper acceleration of the IMU joint's origin over the step, in its frame
//                   at the step's start: R0^T ((R1 v1 - R0 v0) / h - g), R v the origin's world
//                   velocity (v: the free flyer's local linear velocity) at the step's start (0) and
//                   end (1). Time stepping moves a free flyer's origin on a straight line at the
//                   world velocity R0 v+ (integrate.cpp, addFrameTurn), so this is the step's own
//                   acceleration: a free fall reads 0 up to rounding, a body at rest +|g| up.
#include <cmath>
#include <limits>

#include <Eigen/Geometry>

#include "stages.hpp"

namespace stiction {
namespace stages {

namespace {

/// The IMU's joint: the first free flyer whose parent is the universe (a robot's base, the first
/// free body), 0 when there is none.
pinocchio::JointIndex imuJoint(const SimulatorModel& sim) {
  for (pinocchio::JointIndex j : sim.free_flyers)
    if (sim.model.parents[j] == 0) return j;
  return 0;
}

}  // namespace

void sensorsBeforeStep(const SimulatorModel& sim, SimulatorData& sd) {
  const pinocchio::JointIndex j = imuJoint(sim);
  if (j == 0) return;
  sd.work->imu_quaternion0 = sd.q.segment<4>(sim.model.idx_qs[j] + 3);
  sd.work->imu_twist0 = sd.v.segment<6>(sim.model.idx_vs[j]);
}

void sensorsAfterStep(const SimulatorModel& sim, SimulatorData& sd) {
  const int nc = sim.numCandidates();
  const int spheres = static_cast<int>(sim.contacts.size());
  if (sd.out.contact_force.cols() != nc) sd.out.contact_force.resize(3, nc);
  for (int i = 0; i < nc; ++i) {
    const Eigen::Vector3d lam = sd.out.candidate_lambda.col(i);  // (t1, t2, n); unused slots 0
    if (sd.out.candidate_rows[i] == 0 || !sd.out.have_candidate_lambda[i]) {
      sd.out.contact_force.col(i).setZero();
    } else if (i < spheres) {
      const int h = sim.contacts[i].halfspace;
      sd.out.contact_force.col(i) = lam[0] * sd.work->plane_t1.col(h) + lam[1] * sd.work->plane_t2.col(h) +
                                    lam[2] * sd.work->plane_normal.col(h);
    } else {
      sd.out.contact_force.col(i) =
          lam[0] * sd.out.slot_t1.col(i) + lam[1] * sd.out.slot_t2.col(i) + lam[2] * sd.out.slot_normal.col(i);
    }
  }
  const pinocchio::JointIndex j = imuJoint(sim);
  const double h = sd.out.last_dt;
  if (j != 0 && h > 0.0) {
    const auto rotation = [](const auto& xyzw) {
      return Eigen::Quaterniond(xyzw[3], xyzw[0], xyzw[1], xyzw[2]).normalized().toRotationMatrix();
    };
    const Eigen::Matrix3d R0 = rotation(sd.work->imu_quaternion0);
    const Eigen::Matrix3d R1 = rotation(sd.q.segment<4>(sim.model.idx_qs[j] + 3));
    const Eigen::Vector3d v0 = sd.work->imu_twist0.head<3>();
    const Eigen::Vector3d v1 = sd.v.segment<3>(sim.model.idx_vs[j]);
    sd.out.accelerometer = ((R0.transpose() * R1) * v1 - v0) / h - R0.transpose() * sim.model.gravity.linear();
  } else {
    sd.out.accelerometer.setConstant(std::numeric_limits<double>::quiet_NaN());
  }
  sd.out.sensor_time = sd.t;
}

}  // namespace stages
}  // namespace stiction
