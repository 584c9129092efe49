"""A training run's folder: its file names (:mod:`.names`), the one reader (:mod:`.folder`) and the
cameras its capture is seen through by methods that read images (:mod:`.cameras`)."""
