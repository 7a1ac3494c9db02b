"""Controllers: K_θ, the parametric low-level controller (:mod:`.low_level`), the high-level
cascade and its gains (:mod:`.high_level`), and the references (:mod:`.references`)."""
