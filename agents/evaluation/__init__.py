"""The main job: ``radar-track evaluate`` (:mod:`.evaluate`) draws each suite once (:mod:`.suites`), runs every
tracker on the same episodes (:mod:`.runner`, or on Ray workers: :mod:`.parallel`), scores them (:mod:`.metrics`,
:mod:`.downstream`) and draws the figures (:mod:`.plots`)."""
