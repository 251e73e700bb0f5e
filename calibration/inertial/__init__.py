"""Accelerometer and gyroscope fits: the multi-position accelerometer fit (`accel`), its face alignment
(`accel_alignment`) and the gyroscope bias / rate-table fits (`gyro`)."""
