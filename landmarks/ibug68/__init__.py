"""The 68 iBUG landmarks embedded on the template: one face index + three barycentric weights each.

Every landmark is first placed from the template's own structure (eyelid and lip loops, regions, the
midline, geometric extremes), so it follows the template if the template is regenerated; then the
committed corrections (:mod:`landmarks.ibug68.corrections`) move it to where dlib's 68-point predictor -- the
photo fit's source of these 68 points with ``--detector dlib`` -- puts it on renders of the template
(``benchmarks/bench_landmark_offsets.py``; ``docs/landmarks.md``). No rendering happens at run time:
the embedding is a function of the asset and the two tables. Landmarks on the subject's left (+X) and
on the midline are computed, their right-side partners are obtained through the vertex mirror map, so
each pair is an exact mirror image; midline landmarks lie exactly on x = 0 (midline vertices and edges).
The order is the standard iBUG-68 order (:data:`landmarks.ibug68.names.IBUG68_NAMES`); a golden test pins the face ids.

===========  ==========================================================================
indices      geometric placement (before the corrections)
===========  ==========================================================================
0-16         jaw contour: the face's side outline seen from the front (cheeks, jaw,
             chin regions), from the right ear side (-X, at the outer eye corner's height)
             down to the chin (8, lowest midline chin vertex) and up to the left, in 9
             equal arc-length steps per side
17-21/22-26  right brow outer->inner / left brow inner->outer, along the middle of the
             brow band
27-30        nose bridge, on the midline from the top of the upper eyelids to the tip
31-35        lower edge of the nose, right->left (33 = lowest forward midline point)
36-41/42-47  eyelid loops: corners, and the lids at 1/3 and 2/3 of the corner-to-corner width
48-59        outer lip on the vermilion border (the outermost edge ring around the mouth
             loop inside the ``lips`` region): corners, 51/57 on the midline, 50/52 the
             Cupid's bow peaks, 49/53 halfway to the corners, 55-59 under 53..49
60-67        inner lip on the mouth loop (the lips' rim): corners, midline, and under the
             bow peaks
===========  ==========================================================================

Corrected, every landmark stays on its surface: brows on faces touching the ``brows`` region, the
nose base on ``nose`` faces, the outer lip on ``lips`` faces, eyelid points on the eyelid rims, inner
lip points on the mouth loop, midline landmarks on the midline; the static contour on the frontal
outline (each point's direction from the contour centre:
:data:`~landmarks.ibug68.corrections.CONTOUR_ANGLES_DEG`).

:func:`~landmarks.ibug68.positions.landmark_positions` gathers the posed landmarks with one einsum
(differentiable in torch). :func:`~landmarks.ibug68.contour.contour_landmarks` replaces the static jaw
contour with the silhouette seen from a camera (for turned heads), as FLAME's dynamic contour does.

Modules: :mod:`~landmarks.ibug68.names` (the names, their order and the mirror pairs; no torch),
:mod:`~landmarks.ibug68.corrections` (the two committed tables), :mod:`~landmarks.ibug68.embedding`
(:func:`~landmarks.ibug68.embedding.ibug68_embedding`), :mod:`~landmarks.ibug68.positions`,
:mod:`~landmarks.ibug68.contour` (the dynamic jaw contour); how the embedding is built:
:mod:`~landmarks.ibug68.placement` (the geometric placement), :mod:`~landmarks.ibug68.outline` (the
static contour and its candidate lines), :mod:`~landmarks.ibug68.domains` (where a corrected landmark
may lie), :mod:`~landmarks.ibug68.mesh` (points on faces, edges and loops). Names with a leading
underscore are private to this package.
"""
