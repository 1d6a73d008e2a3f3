"""Image pipeline: frame pairs to ranges (thesis ch. 6.1, 6.3, Algorithm 2).

* :mod:`.peaks` - column-wise peak finding, sub-pixel estimators (``column_peaks``, ``refine_peaks``).
* :mod:`.reference` - the thesis's pipeline, faithfully (the baseline).
* :mod:`.fast` - region of interest, vectorised peaks, line fit across columns, ghost rejection.
* :mod:`.geometry` - per-column region of interest and row -> ray table from the calibration.
* :mod:`.postcal` - eq. 6.5 post-calibration in scaled coordinates, Table 6.1 converter, fit.
* :mod:`.measurements` - ``ColumnMeasurements`` (REP 117 ranges) and ``to_laser_scan``.
* :mod:`.pipelines` - ``make_pipeline(name, config)`` and ``VARIANTS``.
* :mod:`.evaluation` - simulated frame pairs and scores against ground truth.
"""
