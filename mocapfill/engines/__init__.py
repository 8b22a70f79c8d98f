"""The engines that registered fill methods share; none is a method of its own.

- :mod:`.lds`: linear dynamical systems (Kalman filter / RTS smoother, E- and M-steps) that DynaMMo and BoLeRO run.
- :mod:`.body_frame`: the per-frame body frame DynaMMo models in.
- :mod:`.weighted_pca`: the distance-weighted PCA of Gløersen & Federolf (``pca`` and the default's local PCA).
- :mod:`.local_pca`: that PCA in each missing marker's local, rotation-aligned neighbourhood.
- :mod:`.gap_uncertainty`: how wrong a fill is likely to be inside a gap (a second opinion's disagreement).
"""
