"""Registration stages: one module per step of the pipeline (see amrst.pipeline)."""
