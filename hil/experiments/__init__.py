"""Experiments that combine calibration, commutation and the predictors on the plant.

``table5`` is the paper's Table 5 scenario (speed profile, scoring against the plant's truth);
``compare`` runs it under the stated protocols (paper, tuned, misspecified, bursts); ``closed_loop``
runs it through the controller on every link and records what a replay needs;
``controller_tuning`` tunes the controller's two filters alike on those recordings and judges them
through the controller; ``robustness`` draws conditions for the predictor
property test; ``identify`` measures the motor model from the plant; ``headline`` is the
calibration headline comparison. They sit above calibration, controller and predictors, which never
import them (``docs/architecture.md``).
"""
