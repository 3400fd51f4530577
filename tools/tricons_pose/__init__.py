"""TriCons-Pose reference implementation (PyTorch, CPU-first) for tricons.

Modules: ``ops`` (custom operators as torch.library ops, exported to ONNX in
domain ``ai.tricons``), ``config`` (paper and shipped configurations,
ablation switches), ``pointnet2`` / ``image_encoder`` / ``model`` (the
network), ``losses``, ``data`` (recordings -> training samples), ``train``.
"""
