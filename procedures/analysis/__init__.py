"""Calibration analysis: pure functions, arrays in, frozen dataclasses out, no I/O.

Every uncertainty named `u_*` is a standard (k=1) uncertainty; `*_k2` names are 2 x that.
Bad input raises `AnalysisError` (a ValueError) whose message names the problem and the fix.

API (names are stable; the procedure engine calls them). Import each name from the module
that defines it: this package re-exports nothing, so its modules can import one another
without an import cycle through the package.

bias.py
    window_mean(rate_dps, sample_rate_hz, noise=None) -> WindowMean
        mean_dps, u_mean_dps (Allan deviation at the window length), duration_s, noise
    estimate_bias(rate_dps, sample_rate_hz, noise=None) -> BiasEstimate
        bias_dps, u_bias_dps, bias_correction_dps, averaging_time_s(accuracy_dps, k=2)
    required_averaging_time_s(noise, bias_accuracy_dps, k=2) -> float (inf if unreachable)
allan.py
    overlapping_adev(rate_dps, sample_rate_hz, taus="octave"|"log"|array) -> AllanDeviation
    fit_noise_model(adev) -> NoiseFit (model: NoiseModel with N, B, K; u_*; regions)
    analyze_allan(rate_dps, sample_rate_hz) -> AllanAnalysis(adev, noise)
    NoiseModel.from_datasheet(arw_deg_per_sqrt_h, bias_instability_deg_per_h, ...)
rate_table.py
    reference_rate_from_encoder(counts, controller_time_s, counts_per_rev,
                                time_resolution_s=1e-3) -> ReferenceRate(rate_dps, u_rate_dps)
    fit_rate_table(input_rate_dps, u_input_rate_dps, output_dps, u_output_dps,
                   full_scale_dps) -> RateTableFit
        scale, u_scale, bias_dps, u_bias_dps, nonlinearity_pct_fs, asymmetry_ppm, k2_per_dps
stop_method.py
    analyze_stop_method(time_s, rate_dps, reference_angle_deg=90, u_reference_angle_deg=0,
                        status=None, settings=None) -> StopMethodResult
        bias_dps, bias_correction_dps, moves (start_s, end_s, measured_angle_deg,
        scale_correction or None when clipped), scale_correction, u_scale_correction, scale
temp_supply_fit.py
    fit_temp_supply([ConditionMeasurement(temp_c, supply_v, bias_dps, u_bias_dps, scale,
                     u_scale), ...], reference_temperature_c=25, reference_supply_v=5)
        -> TempSupplyFit(coefficients: FirstOrderCoefficients, covariances, interaction)
        .as_calibration_dict() gives record.json's pinned `calibration` block
verification.py
    correct_rate(raw_dps, temp_c, supply_v, coefficients) -> corrected deg/s
    correction_uncertainty_dps(fit, rate_dps, temp_c, supply_v) -> u (k=1) the fit adds
    verify_correction(reference_rate_dps, u_reference_rate_dps, corrected_rate_dps,
                      u_corrected_rate_dps, full_scale_dps) -> VerificationResult
consistency.py
    normalised_difference(a, u_a, b, u_b) -> Consistency (E_n, consistent at k=2)
    stop_vs_rate_table(stop_result, rate_table_fit) -> Consistency
"""
