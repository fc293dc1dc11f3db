"""Planning again without starting over: the desired-state cache keyed by the files' content
(``desired_cache``) and the warm session that re-plans from a small edit (``replan``)."""
