"""PDF documents the station issues; they read run folders and the results database only.

    certificate.py    render_certificate(run_folder): certificate.pdf for every verdict
    cert_inputs.py    loading record.json and raw.h5, every defect becomes a stated problem
    cert_sections.py  header, traceability, conditions, results, calibration tables
    cert_plots.py     stop method, rate table, Allan deviation, stabilisation plots
    cert_ramp.py      a ramp calibration's test conditions (span each way, supplies, lag)
    cert_ramp_chart.py the ramp's chart: die temperature over the ramp, residual per plateau
    cert_figures.py   which plots a certificate shows: those of the steps its plan names
    cert_standards.py decision rule, reference standards and ambient conditions
    record_keys.py    typed accessors of record.analysis for the plots (the sections are the
                      models of procedures/runtime/results.py)
    lot_report.py     render_lot_report(db, out, issued=None, **filters): yield, pareto, Cpk,
                      trends
    lot_stats.py      yield, pareto and capability arithmetic (sigma estimator stated there)
    charts.py         general vector charts (line, scatter, shaded windows, log axes, bars)
    pdfdoc.py         reproducible A4 documents: page N of M, SIMULATED BENCH and UNVERIFIED
                      marks, dates
    styles.py         fonts (DejaVu, shipped in fonts/ and embedded), colours, table styles,
                      number formatting

Signing and sealing are the station's (station/certify.py, manifest.py, pdf_signing.py):
this package renders only.
"""
