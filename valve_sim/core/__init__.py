"""The valve model: parameters, equations (1)-(16), integration, steady state.

Lives here: parameter specs and files, the model equations, the RK4 integrator,
the exact steady state, bearing design, linear modes, offline simulation, real-time
stepping and live retuning.
May import: numpy, scipy, yaml, numba; nothing else of valve_sim. No ROS, no
plotting, no bag formats.
"""
