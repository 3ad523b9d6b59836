"""Rigs, skinning, contact IK, retargeting and procedural hands (arrives with the solver issue)."""
