"""A test oracle for the reach-avoid learner: a small system solved exactly.

``system``: the toy double integrator's dynamics, margins and Gymnasium env (env layer, NumPy only);
``oracle``: the exact grid solution, the metrics that score a learned value against it, and the
retraining command (``python -m safemanip.toy``).
"""
