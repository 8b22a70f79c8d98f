"""Runtime plumbing, apart from the data model and the numerics: where tasks run (:mod:`.executor`), BLAS threads
(:mod:`.blas`) and glibc's malloc thresholds (:mod:`.malloc`)."""
