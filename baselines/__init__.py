"""sagfree.baselines (see DESIGN section 2)."""
