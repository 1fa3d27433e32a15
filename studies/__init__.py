"""Study files shipped with sagfree (``sagfree study studies/NAME.toml``; the format is described in
sagfree/reports/study_file.py). ``demo.toml`` is what ``sagfree demo`` runs."""
