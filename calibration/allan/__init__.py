"""The Allan variance noise analysis of a static recording (`ahrsd calibrate allan`): an offline fit, apart from
what the daemon runs. `analysis` is the whole analysis in one call (`analyse_static`, the report, noise.json);
`adev` the Allan deviation and its confidence; `terms` the IEEE Std 952 terms fitted to it (`irls` their compiled
inner loop, `covariance` the estimates' covariance); `correlation` the sensor filter's correlation length;
`resolution` whether the output's LSB lets the noise be read; `kalman` the filter tuning read from the terms.
docs/calibration.md "Allan variance"."""
