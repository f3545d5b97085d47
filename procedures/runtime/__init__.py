"""What a running step works with: its context, the parts and their streams, the record and its
typed results, the raw file, limits, progress, the watchdog, the conditions and cube-face
plans."""
