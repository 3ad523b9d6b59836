"""Retargeting contact-rich hand-object motions between different hands (Kinematic Motion Retargeting,
Lakshmipathy et al. 2025): motions, dense contact pairing, bulk contact transfer, per-frame contact IK,
refinement, B-spline fitting, metrics and the §4.6 baselines."""
