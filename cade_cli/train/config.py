"""A training run's settings (:class:`TrainConfig`), as ``python -m cade_cli.train fit``
takes them and every checkpoint records them."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class TrainConfig:
    out: str
    textures: list[str]
    data_dir: str | None = None
    steps: int = 7000
    batch: int = 4
    height: int = 192
    width: int = 320
    levels: int = 128
    """CadeNet's search width: disparities 0 .. levels - 1 px (the model card's ``levels``)."""
    lr: float = 1e-3
    warmup: int = 200
    seed: int = 0
    device: str = "cpu"
    threads: int = 2
    workers: int = 1
    validate_every: int = 500
    checkpoint_every: int = 250
    coarse_weight: float = 0.5
    stop_after: int | None = None
    """Leave the loop after this step (checkpointed) although the schedule runs to ``steps``."""
    init: str | None = None
    """Start from this checkpoint's weights (fine-tuning: new optimizer, new schedule from step 0);
    a 3x3x3 entry kernel there is reduced to a 1x1x1 one here (``adapt_state_dict``)."""
    padding: str = "zeros"
    """CadeNet's 2D padding mode; cade-v1 … v3 were trained with "replicate"."""
    entry_kernel: int = 1
    """CadeNet's first 3D kernel size; cade-v1 … v3 were trained with 3."""
    channels3d: int = 8
    """Channels of CadeNet's 3D aggregation (8 in cade-v1 … v6; 16 for the accurate tier)."""
    aggregation: str = "3d"
    """CadeNet's aggregation (:data:`~cade_cli.train.model.AGGREGATIONS`): 3x3x3 kernels
    (every shipped model) or separable 2D + 1D ones (the Accuracy II lever)."""
    second_scale: bool = False
    """CadeNet's 1/2-resolution stage between the 1/4 level and the refinement (the
    second-scale lever of Accuracy II; :class:`~cade_cli.train.model.SecondScale`)."""
    census: bool = False
    """Feed CadeNet's aggregation a census cost volume beside the correlation (the
    Accuracy II lever; with ``init`` and ``init_partial`` it starts as the checkpoint)."""
    init_partial: bool = False
    """With ``init``: take only the tensors whose shapes fit (:func:`transferable`), e.g. a
    wider 3D part starting fresh beside cade-v6's 2D features and refinement."""
    misaligned: float = 0.0
    """Share of training pairs whose right view is vertically misaligned
    (:class:`~cade_cli.train.scenes.Misalignment`: up to 1 px, plus a slight roll and zoom);
    cade-v1 … v4 saw perfectly rectified pairs only. Validation pairs stay rectified."""
    real_dir: str | None = None
    """Folder of real training scenes (MiddEval3 layout, ``../shared/data/train-real``)."""
    real_share: float = 0.0
    """Share of training pairs cut from a real scene instead of rendered (needs ``real_dir``);
    cade-v1 … v4: 0."""
    real_hold_out: list[str] = field(default_factory=list)
    """Scenes of ``real_dir`` never trained on, for fitting the learned chooser on scenes the
    network has not memorised (every run before 2026-11-27: none held out)."""
    amp: bool = False
    """Mixed precision: the forward pass and the loss under bf16 autocast (the GPU recipe,
    docs/gpu-recipe.md); weights, gradients and the optimizer stay float32."""
    compile: bool = False
    """Train through ``torch.compile`` of the network (inductor; validation and the saved weights use the network
    itself): the same recipe, fused kernels, rounding a little otherwise. On the 2-vCPU VM a campaign step took
    0.62 s against 0.83 after a few minutes of compiling (docs/research/network-design.md, "the campaign's steps
    faster")."""
    training_mode: str = "cade"
    """How a scene becomes a training pair (:data:`~cade_cli.train.pairs.TRAINING_MODES`):
    ``cade`` (every shipped model), or the paper's comparison modes ``csdl`` and ``pristine``
    (the training ablation); the exported card's ``input`` follows from it."""
    network_input: str | None = None
    """The ``cade`` mode's transform, when not the paper's (``cade-floor``: the contrast-floor
    lever, :data:`~cade_cli.spectral.CONTRAST_FLOOR`); None: the mode's own."""
    architecture: str = "cadenet"
    """The network (:data:`~cade_cli.train.model.ARCHITECTURES`): ``cadenet`` (3D
    aggregation, every model up to cade-v8) or ``cadenet2d`` (the all-2D generation)."""
    width2d: int = 48
    """``cadenet2d``: the 2D U-Net's channels at 1/4 resolution."""
    features2d: int = 32
    """``cadenet2d``: channels of the 1/4-resolution features (the correlation's input)."""
    half_channels: int = 16
    """``cadenet2d``: channels of the 1/2-level refinement."""
    full_refinement: int = 0
    """``cadenet2d``: channels of a full-resolution refinement after the 1/2-level one (0: none)."""
    slice_channels: int = 0
    """``cadenet2d``: channels of the per-disparity aggregation shared by every disparity (0: none)."""
    scene_range: float = 1.0
    """Rendered scenes limit their disparities to ``(levels - 1) * s``, s drawn log-uniformly
    from [``scene_range``, 1] per scene (1: every scene spans the whole range, as before):
    small and large baselines both, instead of a range mostly filled with near objects."""
    eraser: float = 0.0
    """Share of pairs whose right view gets 1-2 rectangles painted over (:func:`~cade_cli.train.scenes.erased`)."""
    ground: float = 0.0
    """Share of rendered scenes with a ground under the objects (:func:`~cade_cli.train.scenes.ground_layer`:
    a road or floor rising from a horizon to near disparities at the bottom); 0: none, no draw."""
    shadows: float = 0.0
    """Share of rendered backgrounds and grounds with shadows cast on them
    (:func:`~cade_cli.train.scenes.cast_shadow`; objects keep their textures); 0: none, no draw."""
    thin: float = 0.0
    """Share of rendered scenes with 1-6 thin structures in front (:func:`~cade_cli.train.scenes.thin_layers`:
    wires, poles, fronds 1-6 px wide at their own disparity: sharp depth edges); 0: none, no draw."""
    floating: float = 0.0
    """Share of rendered scenes made of 10-40 floating objects over a real background (a texture photo
    or a real scene's left view on its own plane: :func:`~cade_cli.train.floating.render_floating`)
    instead of the layered scene; needs texture images or ``real_dir``. 0: none, no draw."""
    asymmetric: float = 0.0
    """Share of pairs (rendered and real) with one view changed by a camera the other did not use
    (:func:`~cade_cli.train.asymmetric.one_view_changed`: vignetting, defocus, gamma, contrast, blur,
    noise, JPEG); the ground truth unchanged. 0: none, no draw."""
    edge_weight: float = 0.0
    """Supervised-loss weight W at depth edges: pixels within 3 px of a ground-truth jump of more
    than 2 px weigh 1 + W, the others 1 (:func:`~cade_cli.train.fit.edge_weights`), and each loss term
    is the weighted mean sum(w l) / sum(w): W moves the emphasis to the edges without changing the
    loss's scale (an error everywhere costs what it did). 0: the plain mean, as before."""
    mask_evidence: bool = False
    """cadenet-iterative only: its convex mask also sees the 1/4 correlation at each of the nine estimates it
    combines (:meth:`~cade_cli.train.net_iterative.CadeNetIterative.evidence`). False: as before."""
    fine_evidence: bool = False
    """cadenet-iterative only: its convex mask also sees, for each of those nine estimates and each 1/2 pixel of
    its cell, the cosine of the two views' 1/2 features there
    (:meth:`~cade_cli.train.net_iterative.CadeNetIterative.fine_evidence_of`). False: as before."""
    mask_pick: float = 0.0
    """cadenet-iterative only: weight of the convex mask's pick loss (:func:`~cade_cli.train.fit.pick_loss`: the
    truth's negative log-likelihood under the mask's mixture of its nine candidates), added to the supervised
    loss, which scores only the mask's blend. 0: none, as before."""
    misaligned_offset: float = 1.0
    """The misaligned pairs' largest vertical offset, px (:class:`~cade_cli.train.scenes.Misalignment`)."""
    feature_consistency: float = 0.0
    """Weight of the cross-spectral feature-consistency loss (FCStereo-style): the 1/4
    features of the left view in two different bands pulled together (1 - cosine); the
    ``cadenet2d`` architecture only. 0: off (no second band is drawn)."""
    crop_schedule: str | None = None
    """Progressive crops, ``"STEP:HxW,..."`` (:func:`parse_crop_schedule`): small crops early
    (cheap steps, local matching), larger ones later (context); None: ``height`` x ``width``."""
    validate_rgb: bool = False
    """Also validate on Middlebury's same-band tasks (the ``*-rgb`` sets of :func:`validation_sets`)."""
    selfsup_dir: str | None = None
    """Folder of multi-lens captures without ground truth (``../shared/data/micasense``; never
    ``msir-outdoor``), rectified band pairs of which train by the self-supervised loss
    (:mod:`~cade_cli.train.selfsup_pairs`, :mod:`~cade_cli.train.selfsup_loss`; issue 38 item 5)."""
    selfsup_cache: str | None = None
    """Where the rectified pairs of ``selfsup_dir`` are cached (npz; built once)."""
    selfsup_share: float = 0.0
    """Share of training pairs cut from the rectified real pairs (0: none, no draw)."""
    selfsup_weight: float = 1.0
    """Weight of the self-supervised loss beside the supervised one."""
    time_budget_s: float | None = None
    """Leave the loop, checkpointed, once this many seconds have passed in this process
    (the GPU recipe works in calls of at most 10 minutes, each resuming the last)."""
    cpu_budget_s: float | None = None
    """Leave the loop, checkpointed, once the run has spent this many CPU-seconds in all (its
    ``cpu_s``, summed over resumes; with ``workers`` 0 that includes rendering the pairs): a
    design bake-off on the CPU gives each design the same CPU-hours however busy the machine is."""
