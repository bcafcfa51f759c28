"""Calibration: excite the robot, identify its model from the record, keep the simulator honest.

    excitation   ExcitationPolicy (a Fourier series per joint inside the profile's limits) and excite()
    identify     identify(): command delay, then a linear regressor on rigid-body inverse dynamics
    write        write_profile(): identified values into the profile, versioned, the old one kept
"""
