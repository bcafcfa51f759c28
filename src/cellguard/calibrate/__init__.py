"""Calibration: excite the robot, identify its model from the record, keep the simulator honest.

    excitation   ExcitationPolicy (a Fourier series per joint inside the profile's limits) and excite()
    identify     identify(): command delay, then a linear regressor on rigid-body inverse dynamics
    write        write_profile(): identified values into the profile, versioned, the old one kept
    mjcf         the calibrated MJCF: identified joint terms and payload in the commissioned model
    bootstrap    replay of a record's commands with known values (identify's own bias)
    torque_model the torque the model needs for a measured motion; residual: the sim-versus-real monitor
    replay       an incident's cycle re-run in the simulator beside its record
    stand        a legged robot on a test stand, for excitation
"""
