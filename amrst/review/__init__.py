"""The technician's judgement: the verdict, manual poses (point pairs, nudge, typed transform) and the quality checks (distances, stem slices)."""
