"""Reports that regenerate the documentation's tables and figures: the results (:mod:`.report`), the held-out
generalisation study (:mod:`.generalisation`), the papers' own checks (:mod:`.paper_checks` with one module per
paper and :mod:`.paper_figures`); :mod:`.readme_blocks` writes generated blocks into the Markdown pages."""
