"""The classical controllers: a cascaded PID, an LQR, the LQR handing over to the PID near the target, and the
residual mix that adds a learned correction to one of them.

Each reads the same observation as a learned policy (:class:`~stewart_gym.sensing.ObservationBuilder`, through
its accessors) and returns a "tilt" action, so the environments, ``evaluate`` and ``deploy`` treat them like any
policy. One module per family:

* :mod:`~stewart_gym.control.parts`: the episodic base every controller uses, and the pieces they share;
* :mod:`~stewart_gym.control.pid`, :mod:`~stewart_gym.control.lqr`, :mod:`~stewart_gym.control.handover`;
* :mod:`~stewart_gym.control.design`: adapting a design to a build (trim tilt, the integral's bound and zone);
* :mod:`~stewart_gym.control.gains`: gains files and bundles, checked, and the controller built from them;
* :mod:`~stewart_gym.control.residual`: a residual policy's action;
* :mod:`~stewart_gym.control.arrays`: the small-array arithmetic of a control step.

The lower bound on settling that compares them lives with the analyses (:mod:`stewart_gym.analysis.settling`).
"""

from stewart_gym.control.arrays import bounded, paired, planar_length
from stewart_gym.control.design import (
    INTEGRAL_MARGIN,
    TRIM_TOLERANCE_US,
    ZONE_MARGIN,
    gains_for_geometry,
    grown_zone,
    trim_tilt,
)
from stewart_gym.control.gains import (
    CLASSICAL,
    CLASSICAL_KINDS,
    checked_design,
    checked_handover,
    classical_controller,
    controller_from_gains,
    design_estimator,
    design_kind,
    shipped_design,
)
from stewart_gym.control.handover import HandoverController, HandoverDesign, HandoverGains
from stewart_gym.control.lqr import LQRController, LQRDesign, LQRGains, design_lqr, lqr_model
from stewart_gym.control.parts import (
    EpisodicController,
    SquareWaveDither,
    TargetFeed,
    integrate_error,
    periods_in_a_row,
    whole_periods,
)
from stewart_gym.control.pid import CascadedPID, PIDGains
from stewart_gym.control.residual import ResidualMix, residual_action

__all__ = ["CLASSICAL", "CLASSICAL_KINDS", "INTEGRAL_MARGIN", "TRIM_TOLERANCE_US", "ZONE_MARGIN", "CascadedPID",
           "EpisodicController", "HandoverController", "HandoverDesign", "HandoverGains", "LQRController", "LQRDesign",
           "LQRGains", "PIDGains", "ResidualMix", "SquareWaveDither", "TargetFeed", "bounded", "checked_design",
           "checked_handover", "classical_controller", "controller_from_gains", "design_estimator", "design_kind",
           "design_lqr", "gains_for_geometry", "grown_zone", "integrate_error", "lqr_model", "paired",
           "periods_in_a_row", "planar_length", "residual_action", "shipped_design", "trim_tilt", "whole_periods"]
