"""ahrsd.calibration"""
