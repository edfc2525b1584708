"""The concealed-effect test sets of the diagnosis's matrix, one per plant: the kernel's
(:mod:`diagnosis.synthetic`), the independent plant's (:mod:`.independent`) and the third
plant's (:mod:`.third`), both plants from :mod:`reference_plants`."""
