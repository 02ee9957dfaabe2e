"""Detection metrics, one module per protocol (``av2``: Argoverse 2's AP, ATE, ASE, AOE, CDS)."""
