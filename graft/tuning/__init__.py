"""`graft tune`: a preset's pipeline measured over a grid of throughput knobs with
simulated actors, the saturated component named, and the report (table, CSV, figure)."""
