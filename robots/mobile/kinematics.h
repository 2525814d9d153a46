// Base velocity -> wheel speed kinematics of the mobile-robots paper §3.3, for the differential (Jetbot) and
// the three-wheel holonomic (Kaya) base. Wheel speeds are angular (rad/s); a positive speed rolls
// a differential wheel forward and drives an omni wheel counter-clockwise about the base.
#pragma once

#include <cmath>

namespace farm::robots::mobile {

struct DiffWheelSpeeds {
  double left = 0, right = 0;
};

// The mobile-robots paper §3.3: W_R = (2V + W R) / (2r), W_L = (2V - W R) / (2r), with V the forward speed, W the
// yaw rate, R the distance between the wheels and r the wheel radius.
inline DiffWheelSpeeds differential_wheel_speeds(double v, double w, double wheel_radius, double wheel_spacing) {
  return {(2 * v - w * wheel_spacing) / (2 * wheel_radius), (2 * v + w * wheel_spacing) / (2 * wheel_radius)};
}

struct OmniWheelSpeeds {
  double a = 0, b = 0, c = 0;
};

// The mobile-robots paper §3.3 with wheels A, B, C at 90, 210 and 330 degrees, L from the center:
// W_A = (-Vx + W L) / r, W_B = (Vx - sqrt(3) Vy + 2 W L) / (2r), W_C = (Vx + sqrt(3) Vy + 2 W L) / (2r).
// Each wheel's rim speed is the base velocity at the wheel along its drive direction
// (-sin t, cos t): the paper's V_i = d_i . (Vx, Vy) + W L.
inline OmniWheelSpeeds holonomic_wheel_speeds(double vx, double vy, double w, double wheel_radius, double base_radius) {
  const double s3 = std::sqrt(3.0), wl = w * base_radius;
  return {(-vx + wl) / wheel_radius, (vx - s3 * vy + 2 * wl) / (2 * wheel_radius),
          (vx + s3 * vy + 2 * wl) / (2 * wheel_radius)};
}

}  // namespace farm::robots::mobile
