"""sagfree.solvers (see DESIGN section 2)."""
