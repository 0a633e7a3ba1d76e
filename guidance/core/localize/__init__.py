"""Stage 1 of the core, "locationd": sensor inputs in, one estimate out (``EstimateState``).

The estimator and everything that moves its state or reads the car's sensors into it: the
filter (``estimator``, with its settings ``estimator_config``), its roles (``motion``, the
predict; ``gates``, whether a measurement may update; ``covariance_edits``, the edits outside
predict and update; ``measurements``, the measurement functions; ``gyro`` and ``turn_fusion``,
a gyro car's turn), the localizer that drives it (``localizer``), the compass deviation card
(``compass_cal``), the parameters a car learns (``learned``, ``wheel_cal``) and the bounds a
state must keep (``state_limits``). Dead reckoning through a CAN gap is
``guidance.core.odometry_gap``, shared: the planner reads its bound too.
"""
