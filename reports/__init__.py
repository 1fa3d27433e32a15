"""sagfree.reports (see DESIGN section 2)."""
