"""Shape mixer: the nonlinear blend of shape keys in lengths and angles, projected, in real time.

A :class:`ShapeMixer` is built once from ``K >= 2`` keys of one mesh (``keys[0]`` is the basis,
like Blender's relative keys).  For weights ``w`` (one per non-basis key, Blender's slider
values) the target is the blend in lengths and angles (the thesis' linear interpolation in
``z``, section 4.2, with several keys)::

    z(w) = z_0 + sum_k w_k (z_k - z_0)

angles on the circle (every difference ``theta_k - theta_0`` wrapped to ``(-pi, pi]``), lengths
floored at :data:`MIN_LENGTH_RATIO` of the basis' (as the shape model's synthesis does).  Keys masked by a vertex
group and keys relative to another key (Blender's *Relative To*) blend as Blender adds them, in lengths and angles:
``z(w) = z_0 + sum_k w_k m_k (z_k - z_rel(k))`` with per-edge factors ``m_k`` (:func:`key_directions`; ``masks`` and
``relative_to`` of :meth:`ShapeMixer.build`).  The mix
is its energy-based projection (Definition 4.3): the minimizer of ``W_q[z(w), Z(X)]`` (3.19), the
energy and weights of :func:`lacore.reconstruction.reconstruct`, in the frame of the basis key.  The
weights are the basis' at every mix, also where the blend's size leaves the band in which
:func:`~lacore.reconstruction.reconstruct` keeps them (keys more than 1.5 times apart in size:
:mod:`lacore.reconstruction.context`, "Target scale"); the build's Newton points and ``polish`` use them too.

A reduced-order model makes a mix cost independent of the vertex count except for writing the
vertices (the thesis' outlook, chapter 5; von Tycowicz, Schulz, Seidel, Hildebrandt 2015):

* offline (:meth:`ShapeMixer.build`): a subspace of vertex positions spanned by the keys, the first
  derivatives of the projection at the keys and Newton vectors (a full Gauss-Newton step from the
  reduced minimizer at the centre, all ones, pairs of keys, the corners of the accurate box and a few
  more weights in ``[0, 1]^(K-1)`` (:func:`.subspace.candidate_weights`), taken in turn, with the
  projection's first derivatives there from the same factorization, then a second time where the
  first step gained more than :data:`REFINE_GAIN`, or, where the Newton vectors go without derivatives
  (``K >= 4``), at a few new weights where an indicator finds the space worst (:data:`EXPLORE_POINTS`);
  :mod:`.subspace`), and a cubature of the reduced energy, a weighted subset of edges (:mod:`.cubature`);
* online (:meth:`ShapeMixer.mix`): Gauss-Newton in the subspace on the cubature edges
  (:mod:`.reduced`), started from the previous mix or the Taylor prediction of the nearest key; where
  the build found the space's error local, one Gauss-Newton step of the full energy on those few vertices
  (:mod:`.local`); an error indicator (:meth:`ShapeMixer.indicator`); ``polish=True`` finishes with the
  full Gauss-Newton projection.

The build costs ``K + C`` sparse factorizations and up to ``min(C_in, 16 - C)`` more in the second round (``C``
candidate weights: 8 for ``K = 3``, 16 for ``K = 4``; ``C_in`` of them in ``[0, 1]^(K-1)``: 4 for ``K = 3``;
:data:`NEWTON_POINTS`), or :data:`EXPLORE_POINTS` more without derivatives, numeric ones of the reconstruction
context's solver (one symbolic analysis for all): they are most of the build at 50k vertices (about 1 s CPU each on
the 50k bar, whose factor has 47 million nonzeros, with an assembly and a solve of 0.1-0.2 s each: 15 of them and 28
s in all on the 2-core AMD EPYC we benchmark on; ``benchmarks/bench_mixer.py``), and at 13k vertices too, where the
cubature fit (:mod:`.cubature`, 0.7-1.5 s there, 4.6 s on the 50k bar) comes next. At 13k vertices the first
factorization's pattern, ordering and symbolic analysis take about 0.8-1.2 s more (on the CC0 body CHOLMOD keeps its
own AMD ordering, whose factor has 5.6 million nonzeros, over the METIS one offered, 6.3 million), and each Newton
vector's reduced minimizer (:data:`PRESOLVE_ITERATIONS` Gauss-Newton steps on the screening's sample of edges, then
one in the space with the full Jacobian, :func:`.subspace.reduced_solve`) 0.03-0.08 s: every point the full step
tries is evaluated with its Jacobian, so its last
evaluation also serves the factorization and the Newton step there, and ``W^(1/2)`` scales ``J U`` in place (the
Newton stage of the CC0 body from 4.2 s to 3.3 s CPU, of the MakeHuman body from 2.0 s to 1.7 s, the same vectors to
the last bit). Scaling the rows of ``J`` before the product instead saved no more (3.9 s to 3.2 s) and changes the
vectors in the last bits, and through the greedy cubature the 50k body's cubature (276 edges instead of 290; largest
error in ``[-0.5, 1.5]^2`` 0.022 % instead of 0.015 %). Fewer training points of the cubature (``2 (K-1)`` random
weights in each box instead of ``3 (K-1)``) saved 0.3 s there but lost accuracy on the MakeHuman body (largest error
in ``[-0.5, 1.5]^2`` 0.011 % to 0.023 %, largest energy ratio in ``[0, 1]^2`` 1.08 to 1.16). Cheaper variants all
lost accuracy on the bar and the CC0 body: Newton vectors by preconditioned conjugate gradients
(:attr:`MixerOptions.newton_pcg_iterations`), derivatives at the basis key only (the CC0 body's median energy ratio
to Gauss-Newton in ``[0, 1]^3`` from 1.27 to 2.86 for 0.3 s), no Newton vector at the centre of ``[0, 1]^(K-1)``
(1.27 to 1.64), one reduced step with the full Jacobian instead of two without the sampled steps before it (the 5k
bar's largest error in ``[-0.5, 1.5]^2`` from 0.44 % to 0.56 %). A mix costs ``O(r^2 n)`` per iteration (``r`` the
reduced size, ``n`` the cubature's edges, both independent of the mesh size) plus ``O(V r)`` to write the vertices.

Examples: ``benchmarks/bench_mixer.py`` measures build, time per mix and the distance to converged
full Gauss-Newton on a bar and two bodies.

Weights outside ``[low, high]`` of :class:`MixerOptions` extrapolate; the result says so
(``in_range`` False and a message) instead of failing, and so does an indicator above
``max_indicator``.

The reduced space lives in the coordinates of a reconstruction context that holds one face per component in the
3-2-1 position (:mod:`lacore.reconstruction.context`): of the faces as well shaped as the reconstruction's default
root, the one nearest the middle of the basis (:func:`~lacore.reconstruction.spanning_trees.centroid_root_faces`;
on the box bars, whose faces all tie, it mixed closer to Gauss-Newton's energy than the default root at an edge of
the box, docs/shape-space.md).  Each mix is then moved rigidly so that the face
:func:`~lacore.reconstruction.reconstruct` holds (:func:`~lacore.reconstruction.spanning_trees.default_root_faces`)
sits where the basis has it: mixes, polished mixes and full reconstructions share one frame.

Files (:meth:`ShapeMixer.save`, :meth:`ShapeMixer.load`): one ``.npz`` with ``format``
(:data:`FORMAT`), ``format_version`` (:data:`FORMAT_VERSION`), the keys, the faces, the options, the
faces the space holds still and the reduced model.
"""

import contextlib
import os
import tempfile
import time
from dataclasses import dataclass, fields, replace

import numpy as np
import scipy.linalg as sl

from ...errors import InputError, LengthsAnglesError, MeshError
from ...geometry.lengths_angles import (check_nondegenerate, lengths_and_angles, lengths_and_angles_jacobian,
                                       wrap_angle)
from ...geometry.topology import MeshTopology, check_vertices
from ...linalg.heap import retained_heap
from ...progress import report
from ...reconstruction import ReconstructionContext, reconstruct
from ...reconstruction.context import triangle_frame
from ...reconstruction.settings import GaussNewtonOptions, ReconstructionSettings
from ...reconstruction.spanning_trees import centroid_root_faces, default_root_faces
from .cubature import fit_cubature
from .files import FORMAT, FORMAT_VERSION, read_mixer_file, write_mixer_file
from .local import LocalCorrection, hot_vertices, space_error_density
from .reduced import ReducedEnergy, edge_stencils
from .subspace import (Expansion, FullProblem, build_space, candidate_weights, exploration_weights, newton_vectors,
                       orthonormal_basis, reduced_normal_equations, space_indicator)

__all__ = ["ShapeMixer", "MixerOptions", "MixResult", "MixerError", "blend_targets", "key_directions", "edge_masks",
           "check_masks", "check_key_count", "MIN_LENGTH_RATIO", "KEYS_ADVICE",
           "FORMAT", "FORMAT_VERSION", "mixer_bytes", "build_mixer_bytes"]

#: Largest automatic reduced size with the Newton vectors' derivatives (:attr:`MixerOptions.newton_derivatives`):
#: a mix costs ``O(r^3)`` per iteration (``r`` columns on ``12 r`` to ``20 r`` cubature edges); the bars' 44 columns
#: (K = 3) take 1.3 ms CPU per mix at 5k vertices and 3.8 ms at 50k (writing the vertices included) on the 2-core AMD
#: EPYC we benchmark on (``benchmarks/bench_mixer.py``); K = 4 would take 79.
AUTO_SIZE = 48

#: A Newton vector whose step would lower the energy at its candidate weight by at most this fraction of the energy
#: there (a tenth of the 2 % the benchmark asks of a mix) joins the space with none of its vectors
#: (:func:`.subspace.newton_vectors`, ``min_gain``): on the MakeHuman body (13k, K = 3), where the keys' space
#: already holds the projection, the space has 23 columns instead of 35 and the cubature takes 0.7 s instead of 1.3 s,
#: for the same energies (median ``energy_goal`` of ``benchmarks/bench_mixer.py`` in ``[0, 1]^2`` 0.10 and 0.11);
#: on the bars every Newton point gains more.
MIN_GAIN = 0.002

#: Rounds after the first revisit the candidates in ``[0, 1]^(K-1)`` whose step in the round before gained more than
#: this fraction of the energy there (the space was far from the projection there).
REFINE_GAIN = 0.01

#: Most Newton points of a build (all rounds): rounds after the first stop there.
NEWTON_POINTS = 16

#: Newton points of the second round of a build whose Newton vectors go without derivatives (``K >= 4``, see
#: :attr:`MixerOptions.newton_derivatives`), instead of revisiting candidates: the weights of the half grid
#: ``{0, 1/2, 1}^(K-1)`` not yet visited (:func:`.subspace.exploration_weights`, 15 for K = 4) where
#: :func:`.subspace.space_indicator` finds the space worst, each from the indicator's reduced minimizer with one
#: reduced step (full Jacobian).  On the CC0 body (13k vertices, K = 4) four revisits instead gained little: the
#: first round's steps had closed the gap at the candidates (the second steps' model decrease 3.4 % and 0.35 % of
#: the energy at ``(1, 1, 1)`` and ``(1, 0, 1)``, nothing at ``(1, 1, 0)`` and ``(0, 1, 1)``, where the energy is
#: next to 0), and the median ``energy_goal`` of ``benchmarks/bench_mixer.py`` in ``[0, 1]^3`` went from 1.98 to
#: 1.85 only; the three facet centres ``(0, 1/2, 1/2)``... to 1.78: the space is worst between the candidates.
#: The indicator chose ``(1/2, 0, 1)``, ``(1/2, 1/2, 1)``, ``(1/2, 1, 1)`` (the three whose Newton steps gain
#: most, of the 15), all with the torso's twist: without derivatives (:data:`EXPLORE_DERIVATIVES` 0) median
#: ``energy_goal`` 1.98 to 1.6-1.8, 2 to 3 weights of 10 within 2 % (at 24 more random weights with converged
#: Gauss-Newton references 1 to 7 of 24, median 3.5 to 1.3), build +0.6-0.8 s; 4 or 5 points did no better, 2
#: worse.
EXPLORE_POINTS = 3

#: The first this many exploration points (the largest indicator) also take the projection's derivatives by the
#: weights there into the space (:func:`.subspace.newton_vectors`; ``K - 1`` columns each, no more
#: factorizations).  Their components outside the space are at most 0.2 % of their length, stiff directions of
#: ``W_q`` the steps miss: on the CC0 body the ``energy_goal`` weights within 2 % went from 3 (none) to 4, 5 and 6
#: of 10 with 1, 2 and 3 (median 1.76, 1.29, 0.92, 0.78; at the 24 more weights 7, 13, 14, 17 of 24), the build
#: (3.7-4.2 s without the second round, paired) took 4.4-4.5, 4.7-5.1, 4.9-5.0 and 5.3 s with 0 to 3 (the
#: cubature's cost grows with the reduced size, 34, 37, 40, 43; was 31), a mix 1.3 ms with 2 (1.0).  With the local
#: correction (:attr:`MixerOptions.local_vertices`) one point does as well as two: 9 of 10 and 22 of 24 within 2 %
#: either way (median ``energy_goal`` 0.55 and 0.47 with one, 0.42 and 0.42 with two), for a build 0.15-0.9 s
#: shorter (4.41-4.63 s against 4.76-5.33 s, paired), which the 5 s budget at 13k vertices needs.
EXPLORE_DERIVATIVES = 1

#: Edges of the sampled reduced energy whose minimizers :func:`.subspace.space_indicator` ranks the exploration
#: weights by (:meth:`ShapeMixer._screening_energy`).
SCREENING_EDGES = 2000

#: Most Gauss-Newton iterations of the reduced energy on the screening's sample of edges for a minimizer in the space
#: (:meth:`ShapeMixer._screening_energy`: the exploration's ranking and the cubature's training points).
SCREENING_ITERATIONS = 10

#: Relative tolerance of those iterations (``ftol`` of :meth:`.reduced.ReducedEnergy.solve`): they stop when a step
#: would lower the sample's energy by less than this fraction of it.  On the CC0 body 5.5 steps a point instead of 8.6
#: with ``1e-12``, the energies within ``4e-7`` of the converged ones (the sample's energy is itself an estimate).
SCREENING_FTOL = 1e-6

#: Gauss-Newton steps of the reduced energy on the screening's sample of edges that move each start of the Newton
#: vectors toward the space's minimizer before the one step with every edge (:meth:`ShapeMixer._presolve`,
#: ``presolve`` of :func:`.subspace.newton_vectors`).  Against two steps with every edge: the reduced solves before
#: the Newton vectors took 1.0 s instead of 1.7 s of the 50k bar's build (12 starts), the Newton stage 0.2-0.25 s
#: less on the 13k bodies; of ``bench_mixer``'s weights within 2 % of the energy of Gauss-Newton the same or more
#: (50k MakeHuman body, outside ``[0, 1]^2``: 9 of 10 instead of 7), the largest RMS errors within 0.004 % of the
#: diagonal of before, or smaller (CC0 body, outside the box: 0.58 % instead of 0.74 %).  One sampled step lost a
#: weight within 2 % on the CC0 body (8 of 10 in the box), ten (nearly the sample's minimizer) four (5 of 10).
PRESOLVE_ITERATIONS = 2

#: Floor of the blended lengths, as a fraction of the basis key's length of the same edge.
MIN_LENGTH_RATIO = 0.01


#: Why a mixer takes few keys, and what to do with the others (:attr:`MixerOptions.max_keys`).
KEYS_ADVICE = ("its build grows steeply with every key: mix the keys that bend or twist large parts, and add "
               "small local ones such as faces and correctives linearly")

#: What to do about a masked or relative key whose shape at weight 1 has no projection (a key relative to an unrelated
#: key is that key's anti-pose at weight 1).
CORNER_ADVICE = "make the key relative to the basis or to the key it corrects, or check its vertex group's weights"


class MixerError(InputError):
    """A mixer file or mixer input that lacore cannot use; the message names it and what to do."""


@dataclass(frozen=True)
class MixerOptions:
    """Settings of a :class:`ShapeMixer`, the one place of its defaults (all scale-free).

    Attributes
    ----------
    reduced_size : int or None
        Largest size of the reduced space (at least ``K-1``: the keys are always in it); None (the
        default): every vector the build makes (the keys, first derivatives at the keys, Newton
        vectors), less the dependent ones.
    low, high : float
        The box ``[low, high]^(K-1)`` of weights where the mixer is accurate (the build trains
        there); outside it a result has ``in_range`` False and says so.
    second_order : bool
        Second derivatives of the projection at the keys in the space (and second-order Taylor
        predictions).  Off by default: with Newton vectors they did not improve the accuracy on the bar
        (largest errors 0.034 % / 0.34 % with, 0.044 % / 0.35 % without) and cost a larger space.
    chord_steps : int
        Chord (Krylov) steps per candidate weight (:mod:`.subspace`); 0 for none.
    newton_rounds : int
        Rounds of Newton vectors (:func:`.subspace.newton_vectors`: a full Gauss-Newton step from the
        reduced minimizer at every candidate weight in turn, each in the space the steps before it
        enlarged; rounds after the first at the candidates in ``[0, 1]^(K-1)`` whose step in the round
        before lowered the energy there by more than :data:`REFINE_GAIN`, up to :data:`NEWTON_POINTS`
        Newton points in all); 0 for none.  Two by default: a Gauss-Newton step from a point of a poor
        space is far from the projection (on the 5k bar at ``w = (1/2, 1/2)``, from 1.6 times the energy
        of converged Gauss-Newton to 1.19; from the final space's minimizer, 1.035, one step reaches
        1.0002), so the second round's steps, from the grown space, are the ones that close the space's
        energy gap.  On the 5k bar (K = 3) the benchmark's mixes in ``[0, 1]^2`` within 2 % of the energy
        of converged Gauss-Newton (its ``energy_goal``) went from 3 to 10 of 10 (median goal margin 2.9 to
        0.20; with the candidates ``(1, 1/2)``, ``(1/2, 1)`` and the cubature's changes of this version:
        :func:`.subspace.candidate_weights`, :func:`.cubature.fit_cubature`), the 50k bar from 2 to 4
        (21.9 to 2.5; build 13.7 s to 27.9 s, reduced size 26 to 44), the MakeHuman body (13k) from 5 to
        10 and at 50k from 4 to 10, the CC0 body (13k, K = 4, no second round within 16 points) from 0 to
        2 (11.3 to 2.0, the halves ``e_a / 2`` its only new candidates; its second round now explores,
        :data:`EXPLORE_POINTS`: 5 of 10, median 0.92; with the local correction, ``local_vertices``, 9 of 10,
        0.55); the largest RMS errors stay
        within the goals (in ``[0, 1]^(K-1)`` at most 0.12 %, in ``[-0.5, 1.5]^(K-1)`` 0.85 %).  What keeps
        the 50k bar and the CC0 body from the goal is the space (the exact minimizer in it has 1.11 and
        1.04 times the energy of Gauss-Newton, median; the CC0 body's excess is mostly local, which the local
        correction recovers, the bar's is spread): on the 50k bar Gauss-Newton needs 3-4 steps from
        the space's minimizer, and preconditioned conjugate gradients or chord steps with a neighbouring
        weight's factorization recover little of a fresh step.
    newton_pcg_iterations : int
        0: every Newton vector with a fresh factorization; else that many conjugate-gradient
        iterations preconditioned by the nearest key's factorization (fewer factorizations, no
        derivatives).  0 by default: with 20 iterations the Newton stage was not cheaper on the 13k
        bodies (PCG iterations cost as much as the factorizations saved) and the CC0 body's largest RMS
        error in ``[0, 1]^3`` grew from 0.03 % to 0.46 %.  Rotating the key's factorization to the pose
        vertex by vertex (as the multiresolution reconstruction's ``"reference"`` fine solver does) does not
        rescue it (measurements: docs/shape-space.md, "What the build cannot skip").
    newton_derivatives : bool or None
        With every Newton vector's factorization, also the first derivatives of the projection by the
        weights at the reduced minimizer (``K-1`` more right-hand sides of the same solve, no more
        factorizations; :func:`.subspace.newton_vectors`) join the space.  They close most of the
        energy gap of the space between the candidate weights: on the 5k bar (K = 3) the median ratio
        of the mix's full energy to that of converged Gauss-Newton in ``[0, 1]^2`` fell from 1.65 to
        1.04 (with the ``20 r`` cubature below), on the 50k bar from 6.0 to 2.1.  None (the default):
        on when the space stays within :data:`AUTO_SIZE` vectors (K <= 3); beyond that the cost of a
        mix (``O(r^3)`` per iteration with the cubature) outweighs them (the CC0 body, K = 4, with
        them and the candidates without the halves ``e_a / 2``: 67 columns, median energy ratio to
        Gauss-Newton 1.055 instead of 1.24, but 5.3 ms per mix and a build of 10.7 s).
    cubature_points : int or None
        Largest number of edges of the cubature; None: ``max(300, 12 r)``, ``20 r`` with the Newton
        vectors' derivatives in the space (stiffer directions: on the MakeHuman body, 13k, K = 3,
        r = 35, the median energy ratio to Gauss-Newton in ``[0, 1]^2`` is 1.135 with ``12 r`` and
        1.039 with ``20 r``).  Meshes with fewer than
        twice as many edges use all (the exact reduced energy).  The fit is trained at the points the
        build solved and at Taylor predictions for random weights moved one reduced Gauss-Newton step
        (full Jacobian) toward the space's minimizers, and matches the whole gradient at every training
        point's own weights besides its pieces (:func:`.cubature.fit_cubature`).  The cubature's share of
        a mix's energy excess (the energy of its minimizer over that of the exact one in the space, median
        in ``[0, 1]^(K-1)``) fell from 1.2 % to 0.2 % on the MakeHuman body (13k, K = 3) and from 0.27 %
        to 0.07 % on the 5k bar; without the step toward the minimizers it is 0.4 % and 0.11 %, and 3.0 %
        instead of 0.7 % on the MakeHuman body at 50k, 1.1 % instead of 0.24 % on the CC0 body (13k, K =
        4), for 0.2-0.4 s more build at 13k vertices and 1.5-1.9 s at 50k.
    cubature_correction : bool
        Correct the cubature's gradient by the exact one at its minimizers of the training weights,
        interpolated in weight space (:meth:`ShapeMixer._shift`).  Off by default: on the MakeHuman
        body (13k) it brought the largest RMS error from 0.008 % to 0.0014 % and the median energy
        excess from 6 % to 1 %, but near the keys (mixes of very low energy) it made the energy up
        to 6 times worse on the bar and did not help on the CC0 body.
    cubature_energy_norm : bool
        Fit the cubature's gradient in the energy norm (``e^T H^{-1} e``, ``H`` the reduced Gauss-Newton
        matrix at the basis key; :func:`.cubature.fit_cubature`) instead of the Euclidean one: a gradient
        error ``e`` moves the minimizer by ``H^{-1} e``, so the soft directions of the space matter most.
        On by default: the cubature's share of a mix's energy excess over converged Gauss-Newton (the
        cubature's minimizer against the exact one in the space, median in ``[0, 1]^(K-1)``) fell from
        5.8 % to 3.5 % on the CC0 body (13k, K = 4), 4.3 % to 2.4 % on the MakeHuman body (13k, K = 3),
        3.9 % to 2.5 % on the 50k bar, and stayed at 1 % on the 5k bar (extrapolated weights gain less and
        sometimes lose: on the 50k bar 7.3 % to 9.1 %), for about the same cubature sizes and times per mix;
        the seeded draw of candidate edges (:func:`.cubature.fit_cubature`) moves these figures by as much
        (MakeHuman body, four draws: 1.6-3.6 % with, 2.7-5.5 % without and 2000 candidates;
        ``benchmarks/bench_mixer.py``; docs/shape-space.md).
    max_iterations : int
        Iterations of one mix (reduced Gauss-Newton).
    polish_iterations : int
        Iterations of a polish (full Gauss-Newton, :func:`lacore.reconstruction.reconstruct`).
    step_tolerance : float
        A mix stops when a step moves the vertices by less than this fraction of the bounding-box
        diagonal (RMS over the vertices).
    max_indicator : float
        Indicator (:meth:`ShapeMixer.indicator`, the estimated RMS error as a fraction of the mix's
        size, :meth:`ShapeMixer.relative_size`) above which a result is flagged (``in_range`` False).
    bending_weight : float or None
        ``eta`` of ``W_q`` (default: the reconstruction's default).
    local_vertices : int
        Vertices of the local correction (:mod:`.local`): after the reduced solve, one Gauss-Newton step of
        the full energy on the vertices where the space misses most, every other vertex held.  The build keeps
        the ``local_vertices`` vertices of the largest error density at its training points when they hold at
        least :data:`.local.HOT_SHARE` of it, else none (the error is not local: a step there would cost time
        for little); 0 turns it off.  150 by default: on the CC0 body (13k vertices, K = 4; the 150 hold 62 %
        of the density, most of it in the left armpit) the benchmark's weights in ``[0, 1]^3`` within 2 % of
        converged Gauss-Newton's energy went from 5 to 9 of 10 (median ``energy_goal`` 0.92 to 0.42; at 24 more
        random weights 14 to 22; the same with the exploration's derivatives at one point since,
        :data:`EXPLORE_DERIVATIVES`, median 0.55), for a step of about 0.65 ms per mix and 0.05 s more build
        (paired); 300 vertices: 22 of the 24 too, a step twice as long.  Its chord step (:data:`.local.CHORD_STEPS`)
        brings the tenth weight in ``[0, 1]^3`` within 2 % for 0.2 ms more.  On the other benchmark meshes
        the 150 hold 11-48 % and the build keeps none.
    max_keys : int
        Most keys a build mixes besides the basis; more are refused at once (:class:`MixerError`, one line,
        :func:`check_key_count`).  Not stored in mixer files.  The Newton candidates grow as ``(K-1)^2 / 2``
        (:func:`.subspace.candidate_weights`), the space with them and the cubature's training with both: on the CC0
        body (13k vertices, one pose key per limb or joint, every slider moving at once) 4, 5 and 6 keys build in
        12, 22 and 44 s CPU (one thread), mix in 5.3, 11 and 16 ms and take 0.66, 1.2 and 2.2 GB more memory to
        build, each further key about doubling them; the RMS distance to converged Gauss-Newton stays within 0.07 %
        of the diagonal in ``[0, 1]^(K-1)`` and 1.1 % outside (``benchmarks/bench_mixer_keys.py``).  6 by default: a
        character's large motions (limbs, torso) mix live, and its small local keys (faces, correctives), whose
        linear sum is already right, stay Blender's.

    Examples
    --------
    >>> options = MixerOptions(low=-1.0, high=2.0)        # build for sliders in [-1, 2]
    >>> options.newton_rounds, options.max_indicator
    (2, 0.01)
    >>> MixerOptions.from_array(options.to_array()) == options   # as stored in mixer files
    True
    """

    reduced_size: int | None = None
    low: float = -0.5
    high: float = 1.5
    second_order: bool = False
    chord_steps: int = 0
    newton_rounds: int = 2
    newton_pcg_iterations: int = 0
    newton_derivatives: bool | None = None
    cubature_points: int | None = None
    cubature_correction: bool = False
    cubature_energy_norm: bool = True
    max_iterations: int = 50
    polish_iterations: int = 300
    step_tolerance: float = 1e-4
    max_indicator: float = 0.01
    bending_weight: float | None = None
    local_vertices: int = 150
    max_keys: int = 6

    def __post_init__(self):
        for name in ("reduced_size", "cubature_points"):
            v = getattr(self, name)
            if v is not None and (int(v) != v or v < 1):
                raise InputError(f"{name} must be a positive integer or None, got {v!r}")
        if not (np.isfinite(self.low) and np.isfinite(self.high) and self.low <= 0.0 and self.high >= 1.0):
            raise InputError(f"the accurate range [low, high] must contain 0 and 1, got [{self.low}, {self.high}]")
        for name in ("max_iterations", "polish_iterations", "max_keys"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise InputError(f"{name} must be a positive integer, got {v!r}")
        for name in ("chord_steps", "newton_rounds", "newton_pcg_iterations", "local_vertices"):
            v = getattr(self, name)
            if int(v) != v or v < 0:
                raise InputError(f"{name} must be a non-negative integer, got {v!r}")
        for name in ("step_tolerance", "max_indicator"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a positive number, got {v!r}")
        if self.bending_weight is not None and not (np.isfinite(self.bending_weight) and self.bending_weight >= 0):
            raise InputError(f"bending_weight must be a non-negative number, got {self.bending_weight!r}")

    @property
    def settings(self):
        """The :class:`~lacore.reconstruction.ReconstructionSettings` of the mixer's energy."""
        if self.bending_weight is None:
            return ReconstructionSettings()
        return ReconstructionSettings(bending_weight=float(self.bending_weight))

    def to_array(self):
        """The options as numbers (None as NaN), in the order of :data:`_OPTION_FIELDS` (for files)."""
        return np.array([np.nan if getattr(self, f) is None else float(getattr(self, f)) for f in _OPTION_FIELDS])

    @classmethod
    def from_array(cls, a):
        """The options of :meth:`to_array`'s numbers.  Files written before the last two fields
        (``cubature_energy_norm``, ``local_vertices``) hold fewer numbers: those fields are off."""
        a = np.asarray(a, float).ravel()
        n = len(_OPTION_FIELDS)
        if n - 2 <= len(a) < n:
            a = np.append(a, np.zeros(n - len(a)))
        if len(a) != n:
            raise MixerError(f"mixer options must be {n} numbers, got {len(a)}")
        kinds = {f.name: f.type for f in fields(cls)}
        kw = {}
        for name, v in zip(_OPTION_FIELDS, a, strict=True):
            if np.isnan(v):
                if "None" not in str(kinds[name]):
                    raise MixerError(f"the option '{name}' is not a number (NaN)")
                kw[name] = None
            elif "bool" in str(kinds[name]):
                kw[name] = bool(v)
            elif "int" in str(kinds[name]):
                kw[name] = int(v)
            else:
                kw[name] = float(v)
        return cls(**kw)


_OPTION_FIELDS = ("reduced_size", "low", "high", "second_order", "chord_steps", "newton_rounds",
                  "newton_pcg_iterations", "newton_derivatives",
                  "cubature_points", "cubature_correction", "max_iterations",
                  "polish_iterations", "step_tolerance", "max_indicator", "bending_weight",
                  "cubature_energy_norm", "local_vertices")


@dataclass(frozen=True)
class MixResult:
    """One mix of a :class:`ShapeMixer`.

    Attributes
    ----------
    vertices : (V, 3) ndarray
        The mixed shape, in the frame of the basis key (its fixed face where the basis has it).
    weights : (K-1,) ndarray
        The weights mixed.
    energy : float
        ``W_q[z(w), Z(vertices)]`` (3.19): the reduced model's estimate (on the cubature's edges, plus the
        exact change of the local correction, :mod:`.local`), or the full energy when ``polished``
        (:meth:`ShapeMixer.full_energy` computes it for any mix).
    indicator : float
        Estimated RMS error over the mix's own size (:meth:`ShapeMixer.indicator`, dimensionless).
    in_range : bool
        False when the weights leave the range where the mixer is accurate (see ``message``).
    message : str
        ``""`` or one line saying what is off and what to do.
    seconds : float
        Wall time of the mix (vertices written included).
    iterations : int
        Solver iterations (reduced, plus full Gauss-Newton ones when polished).
    polished : bool
        Whether the full Gauss-Newton projection produced ``vertices``.

    Examples
    --------
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)
    >>> mixer = ShapeMixer.build([X, bar_pose(X, 0.4, 0.0), bar_pose(X, 0.0, 0.4)], faces)
    >>> r = mixer.mix([0.5, 0.5])
    >>> r.vertices.shape, r.in_range, r.message, r.polished
    ((22, 3), True, '', False)
    >>> far = mixer.mix([3.0, 0.0])
    >>> far.in_range, far.message.split(":")[0]
    (False, 'weights outside [-0.5, 1.5] (key 1 = 3)')
    """

    vertices: np.ndarray
    weights: np.ndarray
    energy: float
    indicator: float
    in_range: bool
    message: str
    seconds: float
    iterations: int
    polished: bool


def key_directions(z_keys, n_edges, relative_to=None, edge_masks=None):
    """The directions ``D_k = m_k (z_k - z_rel(k))`` ``(K-1, 2E)`` of a blend of keys in lengths and angles.

    Blender adds a relative shape key as ``value * g(v) * (K_k - K_rel(k))`` (``g`` the weights of the key's vertex
    group, ``rel(k)`` its *Relative To* key); this is the same in lengths and angles: the difference of the key's
    lengths and angles and its relative key's (angles on the circle, wrapped to ``(-pi, pi]``), scaled per edge by
    the key's mask.

    Parameters
    ----------
    z_keys : (K, 2E) array_like
        Lengths and angles of the keys (``z_keys[0]`` the basis).
    n_edges : int
    relative_to : (K-1,) array_like of int, optional
        Each non-basis key's relative key, an index into ``z_keys`` (default: 0, the basis).
    edge_masks : (K-1, E) array_like, optional
        Each non-basis key's factor per edge (:func:`edge_masks`; default: 1).

    Returns
    -------
    D : (K-1, 2E) ndarray

    Examples
    --------
    >>> import numpy as np
    >>> z = np.array([[1.0, 0.0], [2.0, 0.5], [3.0, 0.5]])   # one edge: length, angle
    >>> key_directions(z, 1, relative_to=[0, 1], edge_masks=[[1.0], [0.5]]).tolist()
    [[1.0, 0.5], [0.5, 0.0]]
    """
    Z = np.asarray(z_keys, float)
    rel = np.zeros(len(Z) - 1, np.int64) if relative_to is None else np.asarray(relative_to, np.int64)
    D = Z[1:] - Z[rel]
    D[:, n_edges:] = wrap_angle(D[:, n_edges:])
    if edge_masks is not None:
        M = np.asarray(edge_masks, float)
        D[:, :n_edges] *= M
        D[:, n_edges:] *= M
    return D


def edge_masks(masks, edges):
    """Per-edge factors ``(K-1, E)`` of per-vertex ones ``(K-1, V)``: the mean of an edge's two vertices'.

    Parameters
    ----------
    masks : (K-1, V) array_like
        Each non-basis key's factor per vertex (Blender's vertex-group weights).
    edges : (E, 2) array_like of int
        :attr:`lacore.MeshTopology.edges`.

    Returns
    -------
    (K-1, E) ndarray

    Examples
    --------
    >>> edge_masks([[0.0, 1.0, 1.0]], [[0, 1], [1, 2]]).tolist()
    [[0.5, 1.0]]
    """
    M = np.asarray(masks, float)
    e = np.asarray(edges)
    return 0.5 * (M[:, e[:, 0]] + M[:, e[:, 1]])


def _blend(z0, D, weights, n_edges, min_length_ratio):
    z = z0 + np.asarray(weights, float) @ D
    z[..., n_edges:] = wrap_angle(z[..., n_edges:])
    z[..., :n_edges] = np.maximum(z[..., :n_edges], min_length_ratio * z0[:n_edges])
    return z


def blend_targets(z_keys, weights, n_edges, min_length_ratio=MIN_LENGTH_RATIO, *, relative_to=None, edge_masks=None):
    """``z(w) = z_0 + sum_k w_k D_k``, ``D_k = m_k (z_k - z_rel(k))`` (:func:`key_directions`), lengths floored.

    With the defaults (every key relative to the basis, no mask) ``z(w) = z_0 + sum_k w_k (z_k - z_0)``.

    Parameters
    ----------
    z_keys : (K, 2E) array_like
        Lengths and angles of the keys (``z_keys[0]`` the basis).
    weights : (K-1,) or (N, K-1) array_like
    n_edges : int
    min_length_ratio : float
        Lengths below this fraction of the basis' are raised to it.
    relative_to : (K-1,) array_like of int, optional
        Each non-basis key's relative key (index into ``z_keys``; default 0, the basis).
    edge_masks : (K-1, E) array_like, optional
        Each non-basis key's factor per edge (:func:`edge_masks`; default 1).

    Returns
    -------
    z : (2E,) or (N, 2E) ndarray

    Examples
    --------
    >>> import numpy as np
    >>> z = np.array([[1.0, 3.0], [2.0, -3.0]])         # one edge: length, angle
    >>> blend_targets(z, [0.5], 1).round(4)             # the angle goes the short way round through pi
    array([1.5   , 3.1416])
    """
    Z = np.asarray(z_keys, float)
    return _blend(Z[0], key_directions(Z, n_edges, relative_to, edge_masks), weights, n_edges, min_length_ratio)


#: A key whose edge lengths (relative to the basis') and dihedral angles (radians) all differ from the basis' by
#: at most this equals the basis up to a rigid motion and rounding: it has nothing to mix.
SAME_SHAPE_TOL = 1e-9


def check_keys(keys, faces, names=None):
    """Validated keys of a mixer and their topology; raises naming the key and what to do.

    Parameters
    ----------
    keys : (K, V, 3) array_like
        ``keys[0]`` the basis.
    faces : (F, 3) array_like of int, or MeshTopology
    names : sequence of str, optional
        How the messages name the keys (default: ``"key k"``).

    Returns
    -------
    keys : (K, V, 3) float64 ndarray
    topology : MeshTopology

    Raises
    ------
    MeshError
        Bad faces, fewer than two keys, another vertex count, NaN or infinite coordinates, degenerate triangles
        in a key (:func:`lacore.geometry.lengths_angles.check_nondegenerate`).
    MixerError
        No key differs from the basis in an edge length or a dihedral angle by more than
        :data:`SAME_SHAPE_TOL` (every key is the basis up to a rigid motion: nothing to mix).

    Examples
    --------
    >>> from lacore.samples.bar import bar_mesh
    >>> X, faces = bar_mesh(n_along=4, n_side=1)
    >>> try:
    ...     check_keys([X, X + 1.0], faces, names=["shape key 'Basis'", "shape key 'Key 1'"])
    ... except MixerError as e:
    ...     print(str(e).split(";")[1].split(":")[0])
     shape key 'Key 1' is the basis up to a rigid motion)
    """
    F = np.asarray(faces.faces if isinstance(faces, MeshTopology) else faces)
    if F.ndim != 2 or F.shape[1] != 3 or F.size == 0 or F.dtype.kind not in "iu":
        raise MeshError(f"faces must be a non-empty (F, 3) integer array, got shape {F.shape}")
    try:
        K = np.asarray(keys, float)
    except (TypeError, ValueError):
        raise MeshError("keys must be a (K, V, 3) array of numbers (K >= 2 keys of one mesh)") from None
    if K.ndim != 3 or K.shape[2] != 3:
        raise MeshError(f"keys must be a (K, V, 3) array (K >= 2 keys of one mesh), got shape {K.shape}")
    if K.shape[0] < 2:
        raise MeshError(f"a mixer needs at least 2 keys (the basis and one more), got {K.shape[0]}")
    names = [f"key {k}" for k in range(len(K))] if names is None else [str(n) for n in names]
    topo = MeshTopology.from_faces(F.astype(np.int64), n_vertices=K.shape[1])
    for k in range(K.shape[0]):
        check_vertices(K[k], K.shape[1], name=names[k])
        try:
            check_nondegenerate(K[k], topo)
        except MeshError as exc:
            raise MeshError(f"{names[k]}{' (the basis)' if k == 0 else ''}: {exc}; move the vertices of those faces "
                            "apart in that key, or leave the key out") from None
    E = topo.n_edges
    z = np.stack([lengths_and_angles(k, topo, check=False) for k in K])
    change = np.maximum(np.abs(z[1:, :E] - z[0, :E]) / z[0, :E], np.abs(wrap_angle(z[1:, E:] - z[0, E:]))).max(axis=1)
    if not np.any(change > SAME_SHAPE_TOL):
        same = ", ".join(names[1:4]) + (" ..." if len(K) > 4 else "")
        raise MixerError(f"no key differs from the basis {names[0]} in an edge length or a dihedral angle (by more "
                         f"than {SAME_SHAPE_TOL:g}; {same} {'is' if len(K) == 2 else 'are'} the basis up to a rigid "
                         "motion): there is nothing to mix; shape a key first")
    return K, topo


def check_key_count(n_keys, options=None, raise_with="raise MixerOptions.max_keys"):
    """:class:`MixerError` (one line: the count, the limit, :data:`KEYS_ADVICE` and ``raise_with``) when ``n_keys``
    keys (the basis included) are more than a mixer with ``options`` takes (:attr:`MixerOptions.max_keys`).

    Examples
    --------
    >>> check_key_count(7)                      # the basis and 6 keys
    >>> check_key_count(8, MixerOptions(max_keys=7))
    """
    limit = (options or MixerOptions()).max_keys
    if n_keys - 1 > limit:
        raise MixerError(f"{n_keys - 1} keys to mix besides the basis: a mixer mixes at most {limit} ({KEYS_ADVICE}, "
                         f"or {raise_with})")


def check_masks(masks, relative_to, n_keys, n_vertices, names=None):
    """Validated masks and relative keys of a mixer's non-basis keys; raises naming the key and what to do.

    Parameters
    ----------
    masks : (K-1, V) array_like or None
        Each non-basis key's factor per vertex, in ``[0, 1]`` (Blender's vertex-group weights); None: 1.
    relative_to : (K-1,) array_like of int or None
        Each non-basis key's relative key, an index into the keys (0 the basis, never the key itself); None: 0.
    n_keys, n_vertices : int
        ``K`` and ``V``.
    names : sequence of str, optional
        How the messages name the keys (default ``"key k"``).

    Returns
    -------
    masks : (K-1, V) float64 ndarray
    relative_to : (K-1,) int64 ndarray

    Raises
    ------
    MixerError
        Another shape, NaN or a factor outside ``[0, 1]``, a relative key out of range or the key itself.

    Examples
    --------
    >>> masks, rel = check_masks(None, [0, 1], 3, 4)
    >>> masks.shape, rel.tolist()
    ((2, 4), [0, 1])
    >>> try:
    ...     check_masks(None, [0, 2], 3, 4)
    ... except MixerError as e:
    ...     print(str(e).split(":")[0])
    key 2 is relative to itself
    """
    m = n_keys - 1
    names = [f"key {k}" for k in range(n_keys)] if names is None else [str(n) for n in names]
    if masks is None:
        M = np.ones((m, n_vertices))
    else:
        try:
            if np.iscomplexobj(masks):  # (float() would drop the imaginary parts)
                raise TypeError("complex masks")
            M = np.array(masks, float)
        except (TypeError, ValueError):
            raise MixerError(f"masks must be a ({m}, {n_vertices}) array of numbers in [0, 1], one row per non-basis "
                             "key") from None
        if M.shape != (m, n_vertices):
            raise MixerError(f"masks must be a ({m}, {n_vertices}) array, one row of vertex factors per non-basis key, "
                             f"got shape {M.shape}")
        bad = np.flatnonzero(~np.all((M >= 0.0) & (M <= 1.0), axis=1))
        if bad.size:
            raise MixerError(f"the mask of {names[bad[0] + 1]} has factors outside [0, 1] or NaN: vertex-group weights "
                             "lie in [0, 1]; clamp them")
    if relative_to is None:
        R = np.zeros(m, np.int64)
    else:
        try:
            R = np.asarray(relative_to)
            ok = R.shape == (m,) and (R.dtype.kind in "iu" or (R.dtype.kind == "f" and np.all(np.isfinite(R))
                                                                and np.all(R == np.round(R))))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise MixerError(f"relative_to must be {m} key indices, one per non-basis key (0: the basis)")
        R = R.astype(np.int64)
        out = np.flatnonzero((R < 0) | (R >= n_keys))
        if out.size:
            raise MixerError(f"{names[out[0] + 1]} is relative to key index {R[out[0]]}: there are keys 0 to "
                             f"{n_keys - 1}")
        self_rel = np.flatnonzero(R == np.arange(1, n_keys))
        if self_rel.size:
            raise MixerError(f"{names[self_rel[0] + 1]} is relative to itself: it adds nothing; leave it out or make "
                             "it relative to another key")
    return M, R


#: Inverse-distance weights of the cubature's gradient corrections: ``|w - w_s|^(-2 p)``.
_CORRECTION_POWER = 2


class _Stopwatch:
    """Wall and CPU seconds by stage (a stage timed twice adds up)."""

    def __init__(self):
        self.wall, self.cpu = {}, {}

    @contextlib.contextmanager
    def __call__(self, name):
        t, c = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.wall[name] = self.wall.get(name, 0.0) + time.perf_counter() - t
            self.cpu[name] = self.cpu.get(name, 0.0) + time.process_time() - c


class ShapeMixer:
    """Nonlinear mixing of shape keys in lengths and angles (see the module docstring).

    Build with :meth:`build` (or :meth:`load` a saved one), then call :meth:`mix` with the weights.
    A mixer remembers its last mix (the warm start of the next); use one mixer per thread.

    Examples
    --------
    >>> import numpy as np
    >>> from lacore.samples.bar import bar_mesh, bar_pose
    >>> X, faces = bar_mesh(n_along=4, n_side=1)
    >>> mixer = ShapeMixer.build([X, bar_pose(X, 0.4, 0.0), bar_pose(X, 0.0, 0.4)], faces)
    >>> r = mixer.mix([1.0, 0.0])                    # the first key (in the basis' frame)
    >>> from lacore.geometry.rigid import rigid_rms
    >>> bool(rigid_rms(r.vertices, bar_pose(X, 0.4, 0.0)) < 1e-6 * np.ptp(X)), r.in_range
    (True, True)
    >>> mixer.mix([2.5, 0.0]).in_range               # far outside the accurate range: it says so
    False
    """

    def __init__(self, keys, faces, options=None, *, masks=None, relative_to=None, _topology=None, _corners=None,
                 _fixed_faces=None):
        self.options = MixerOptions() if options is None else options
        if _topology is None:
            keys, _topology = check_keys(keys, faces)
        self.keys = np.asarray(keys, float)
        self.topology = _topology
        self.faces = self.topology.faces
        E = self.n_edges = self.topology.n_edges
        self.masks, self.relative_to = check_masks(masks, relative_to, self.n_keys, self.n_vertices)
        # keys whose blend at weight 1 is not the key itself: a mask below 1 somewhere, or another relative key
        self._derived = (self.relative_to != 0) | np.any(self.masks != 1.0, axis=1)
        em = edge_masks(self.masks, self.topology.edges) if self._derived.any() else None
        # its own context, with the basis' weights for every target (reconstruction.context, "Target scale")
        # the reduced space's coordinates hold the tied face nearest the middle (centroid_root_faces); mixes are
        # placed as reconstruct places its results (_place)
        fixed = centroid_root_faces(self.topology, self.keys[0]) if _fixed_faces is None else _fixed_faces
        settings = replace(self.options.settings, fixed_face=np.asarray(fixed, np.int64))
        ctx = self._context = ReconstructionContext(self.topology, self.keys[0], settings)
        self._set_placement()
        ctx.follows_target_scale = False
        self.z_keys = np.stack([lengths_and_angles(k, self.topology) for k in self.keys])
        self._directions = key_directions(self.z_keys, E, self.relative_to, em)
        if em is not None:
            change = np.maximum(np.abs(self._directions[:, :E]) / self.z_keys[0, :E],
                                np.abs(self._directions[:, E:])).max(axis=1)
            if not np.any(change > SAME_SHAPE_TOL):
                raise MixerError("every key's mask is 0 where it differs from its relative key: there is nothing to "
                                 "mix; check the masks (vertex groups) and relative keys")
        self._length_gains = self._directions[:, :E].sum(axis=1) / self.z_keys[0, :E].sum()   # relative_size
        zi = np.stack([ctx.internal_z(z) for z in self.z_keys])
        dz = key_directions(zi, E, self.relative_to, em)
        w = np.array(ctx.residual_weights, float)
        w[E:][self.topology.is_boundary_edge] = 0.0
        self._problem = FullProblem(ctx, zi, dz, MIN_LENGTH_RATIO * zi[0, :E], w)
        # the shapes at the weights 0 and e_k: the keys, or the projections of derived keys (_project_corners)
        self._corners = self.keys.copy() if _corners is None else np.asarray(_corners, float)
        self._key_x = np.stack([ctx.to_canonical(k).ravel() for k in self._corners])
        self._stencils = edge_stencils(self.topology)
        self._screening = None                              # (edges, weights), :meth:`_screening_sample`
        self._gn = GaussNewtonOptions(max_iterations=self.options.polish_iterations)
        self.diagonal = float(np.linalg.norm(np.ptp(self.keys[0], axis=0))) or 1.0
        self.build_seconds = {}
        self.build_cpu_seconds = {}
        self._last_q = None
        self.basis = None
        self._error_w = self._error_v = None
        self._corr_w = self._corr = None
        self._derivatives = False
        self._local = None

    # ------------------------------------------------------------------ building
    @classmethod
    def build(cls, keys, faces, options=None, *, masks=None, relative_to=None, names=None, progress=None):
        """A mixer of ``keys`` ``(K, V, 3)`` (``keys[0]`` the basis) on ``faces`` ``(F, 3)``.

        Parameters
        ----------
        keys : (K, V, 3) array_like
            K >= 2 shapes of one mesh in dense correspondence.
        faces : (F, 3) array_like of int
        options : MixerOptions, optional
        masks : (K-1, V) array_like, optional
            Each non-basis key's factor per vertex in ``[0, 1]``, Blender's vertex-group weights of the key (default:
            1 everywhere).  An edge's factor is the mean of its vertices' (:func:`edge_masks`).
        relative_to : (K-1,) array_like of int, optional
            Each non-basis key's *Relative To* key, an index into ``keys`` (default: 0, the basis).  The target of
            weights ``w`` is ``z_0 + sum_k w_k m_k (z_k - z_rel(k))`` (:func:`key_directions`), as Blender adds
            ``w_k g(v) (K_k - K_rel(k))``.  For a key with a mask or another relative key the shape at weight 1
            alone is not the key: the build projects that target first (one Gauss-Newton reconstruction each,
            from Blender's linear blend).
        names : sequence of str, optional
            The keys' names for progress and error messages (default ``key 0``, ``key 1`` ...), as for
            :func:`check_keys`.
        progress : callable, optional
            ``progress(done, total, message)``; returning True raises :class:`lacore.progress.Cancelled`.

        Raises
        ------
        MeshError
            Keys of different vertex counts, fewer than two keys, bad faces, NaN coordinates, degenerate
            triangles in a key.
        MixerError
            No key differs from the basis in lengths or angles (nothing to mix); bad masks or relative keys
            (:func:`check_masks`); a key's blend at weight 1 that no mesh comes near (no projection).

        Examples
        --------
        >>> import numpy as np
        >>> from lacore.samples.bar import bar_mesh, bar_pose
        >>> X, faces = bar_mesh(n_along=4, n_side=1)
        >>> A, B = bar_pose(X, 0.4, 0.0), bar_pose(X, 0.4, 0.3)       # B: a twist on top of the bend A
        >>> half = (X[:, 0] > X[:, 0].mean()).astype(float)           # a vertex group: one half of the bar
        >>> mixer = ShapeMixer.build([X, A, B], faces, masks=[half, np.ones(len(X))], relative_to=[0, 1])
        >>> from lacore.geometry.rigid import rigid_rms
        >>> bool(rigid_rms(mixer.mix([0.0, 1.0]).vertices, X) > 0.01)   # the twist B - A alone, on the straight bar
        True
        """
        with retained_heap():  # its factorizations allocate and free the same blocks (lacore.linalg.heap)
            return cls._build(keys, faces, options, masks=masks, relative_to=relative_to, names=names,
                              progress=progress)

    @classmethod
    def _build(cls, keys, faces, options, *, masks, relative_to, names, progress):
        if options is not None and not isinstance(options, MixerOptions):
            raise InputError(f"options must be MixerOptions, got {type(options).__name__}")
        if hasattr(keys, "__len__"):
            check_key_count(len(keys), options)
        watch = _Stopwatch()
        report(progress, 0, 4, "lengths and angles of the keys")
        with watch("setup"):
            mixer = cls(keys, faces, options, masks=masks, relative_to=relative_to)
        o = mixer.options
        if names is not None:
            names = [str(n) for n in names]
            if len(names) != mixer.n_keys:
                raise InputError(f"names must name the {mixer.n_keys} keys, got {len(names)}")
        if o.reduced_size is not None and o.reduced_size < mixer.n_keys - 1:
            raise InputError(f"reduced_size {o.reduced_size} is below the {mixer.n_keys - 1} non-basis keys: the space "
                             "holds at least the keys")
        if mixer._derived.any():
            with watch("corners"):
                mixer._project_corners(progress, names)
        P = mixer._problem
        size = mixer._context.size
        vectors, exps = build_space(P, mixer._key_x, o.low, o.high, second_order=o.second_order,
                                    chord_steps=o.chord_steps, size=size, stage=watch,
                                    progress=None if progress is None else (
                                        lambda d, t, m: progress(1, 4, m)))
        report(progress, 2, 4, "basis")
        with watch("basis"):
            U, _ = orthonormal_basis(vectors, None if o.newton_rounds else o.reduced_size, keep=mixer.n_keys - 1)
            mixer._set_basis(U, exps)
        x0 = mixer._key_x[0]
        all_cands = candidate_weights(mixer.n_keys - 1, o.low, o.high)
        inside = [c for c in all_cands if c.min() >= 0.0 and c.max() <= 1.0]
        derivatives = o.newton_derivatives
        if derivatives is None:
            m = mixer.n_keys - 1
            starts = len(all_cands)
            for _ in range(1, o.newton_rounds):
                starts += min(len(inside), max(0, NEWTON_POINTS - starts))
            derivatives = m * (1 + mixer.n_keys) + starts * (1 + m) <= AUTO_SIZE
        mixer._derivatives = bool(derivatives and o.newton_rounds and not o.newton_pcg_iterations)
        latest, gains = {}, {}  # the last error estimate and relative model decrease at every candidate
        n_points, space = 0, None
        keys_w = [np.zeros(mixer.n_keys - 1)] + list(np.eye(mixer.n_keys - 1))
        for rnd in range(o.newton_rounds):
            last = rnd == o.newton_rounds - 1
            exploring = rnd == 1 and not derivatives
            if rnd == 0:
                cands = list(all_cands)
            elif not exploring:  # the candidates in [0, 1]^m whose last step gained, the largest gains first
                cands = [c for c in inside if not gains[tuple(c)] <= REFINE_GAIN]
                cands = sorted(cands, key=lambda c: -gains[tuple(c)])[:max(0, NEWTON_POINTS - n_points)]
            else:  # no derivatives at every point: new weights of the half grid where the space is worst
                pool = exploration_weights(mixer.n_keys - 1, keys_w + all_cands)
                with watch("newton_vectors"):
                    sampled = mixer._screening_energy()
                    score, screened = space_indicator(
                        P, x0, mixer.basis, [(wc, mixer._start(wc)) for wc in pool],
                        lambda wk, q0, e=sampled: mixer._screened(e, wk, q0))
                order = np.argsort(-score, kind="stable")[:EXPLORE_POINTS]
                cands = [pool[i] for i in order]
                starts = {tuple(pool[i]): screened[i] for i in order}
                with_derivatives = {tuple(pool[i]) for i in order[:EXPLORE_DERIVATIVES]}
                all_cands = all_cands + cands
            # the farthest from the centre of [0, 1]^m first: the inner ones see their steps
            cands = sorted(cands, key=lambda w: -float(np.abs(w - 0.5).max()))
            if cands:
                report(progress, 2, 4, f"Newton vectors, round {rnd + 1}")
                with watch("newton_vectors"):
                    steps, presolve = 1, None
                    if exploring:  # from the screening's minimizers, one reduced step (full Jacobian)
                        begin = [(wc, starts[tuple(wc)]) for wc in cands]
                        deriv = [tuple(wc) in with_derivatives for wc in cands]
                    else:  # from the nearest expansion, sampled steps, then one reduced step (full Jacobian)
                        begin, deriv = [(wc, mixer._start(wc)) for wc in cands], derivatives
                        if o.newton_pcg_iterations:
                            steps = 2
                        else:
                            presolve = mixer._presolve
                    new, points, errors, gain, space = newton_vectors(
                        P, x0, mixer.basis, begin, size, reduced_iterations=steps, presolve=presolve,
                        keys=list(zip(keys_w, mixer._key_x, strict=True)), pcg_iterations=o.newton_pcg_iterations,
                        derivatives=deriv, min_gain=0.0 if o.newton_pcg_iterations else MIN_GAIN,
                        progress=None if progress is None else (
                            lambda d, t, msg, rnd=rnd: progress(2, 4, f"round {rnd + 1}: {msg}")))
                    n_points += len(cands)
                    latest.update({tuple(c): e for c, e in zip(cands, errors, strict=True)})
                    gains.update({tuple(c): g for c, g in zip(cands, gain, strict=True)})
                    mixer._error_w = np.array(keys_w + all_cands)
                    mixer._error_v = np.concatenate([np.zeros(mixer.n_keys), [latest[tuple(c)] for c in all_cands]])
                    vectors += new
                    done = {tuple(wc) for wc, _ in points}
                    exps = [e for e in exps if e.D1 is not None or tuple(e.w) not in done] + [
                        Expansion(wc, x) for wc, x in points]
            if cands or last:
                with watch("basis"):
                    if space is not None and (o.reduced_size is None or not last):
                        U = space    # the space the Newton vectors were taken in, grown by them: no new SVD
                    else:
                        U, _ = orthonormal_basis(vectors, o.reduced_size if last else None, keep=mixer.n_keys - 1)
                    mixer._set_basis(U, exps)
        with watch("basis"):
            mixer._output_basis()                            # of the final basis only
        report(progress, 3, 4, "cubature")
        with watch("cubature"):
            mixer._fit_cubature()
        mixer.build_seconds = dict(watch.wall, total=sum(watch.wall.values()))
        mixer.build_cpu_seconds = dict(watch.cpu, total=sum(watch.cpu.values()))
        report(progress, 4, 4, "done")
        return mixer

    def _project_corners(self, progress=None, names=None):
        """The shapes at the weights ``e_k`` of the derived keys (a mask or another relative key): the projections of
        their targets by Gauss-Newton from Blender's linear blend ``B + m_k (K_k - K_rel(k))``; ``progress`` is
        reported (and may cancel) before each.  A projection that does not succeed
        (:mod:`lacore.reconstruction.checks`) is a :class:`MixerError` naming the key (``names``, as for
        :meth:`build`): the build takes these shapes as exact."""
        m = self.n_keys - 1
        names = [f"key {k}" for k in range(self.n_keys)] if names is None else names
        for k in np.flatnonzero(self._derived) + 1:
            report(progress, 0, 4, f"{names[k]} at weight 1, its mask and relative key applied")
            w = np.zeros(m)
            w[k - 1] = 1.0
            start = self.keys[0] + self.masks[k - 1][:, None] * (self.keys[k] - self.keys[self.relative_to[k - 1]])
            try:
                res = reconstruct(self.target(w), self.topology, self.keys[0], context=self._context,
                                  options=self._gn, initial_vertices=start)
            except LengthsAnglesError as exc:
                raise MixerError(f"{names[k]} at weight 1 (its mask and relative key applied) is no shape a mesh "
                                 f"comes near: {exc}; {CORNER_ADVICE}") from None
            if not res.success:  # the build takes this shape as exact (the indicator is 0 there)
                raise MixerError(f"{names[k]} at weight 1 (its mask and relative key applied) has no projection: "
                                 f"{res.message}; {CORNER_ADVICE} (in Python, MixerOptions.polish_iterations allows "
                                 "more iterations)")
            self._corners[k] = res.vertices
            self._key_x[k] = self._context.to_canonical(res.vertices).ravel()

    def _set_basis(self, U, exps):
        """Reduced expansions ``(w, q, A (r, m) or None, T (m, m, r) or None)`` from full ones (the output basis
        follows with :meth:`_output_basis`)."""
        self.basis = U
        x0 = self._key_x[0]
        self._exp_w = np.array([e.w for e in exps])
        self._exp_q = np.array([U.T @ (e.x - x0) for e in exps])
        m, r = self.n_keys - 1, U.shape[1]
        self._exp_order = np.array([0 if e.D1 is None else (1 if e.T is None else 2) for e in exps])
        self._exp_A = np.array([np.zeros((r, m)) if e.D1 is None else (e.D1 @ U).T for e in exps])
        self._exp_T = np.array([np.zeros((m, m, r)) if e.T is None else (e.T.reshape(m * m, -1) @ U).reshape(m, m, r)
                                for e in exps])

    def _set_placement(self):
        """``(face vertices, reference frame, vertex indices)`` per component of the faces :func:`reconstruct` holds
        still (indices None for one component), or None where they are the context's."""
        own = default_root_faces(self.topology, vertices=self.keys[0])
        self._place_frames = None
        if not np.array_equal(own, self._context.fixed_faces):
            comp = self._context.vertex_component
            self._place_frames = [(self.faces[f], triangle_frame(self.keys[0], self.faces[f]),
                                   None if len(own) == 1 else np.flatnonzero(comp == c)) for c, f in enumerate(own)]

    def _place(self, X):
        """``X`` ``(V, 3)`` moved rigidly (per component) so that the face :func:`reconstruct` holds still sits where
        the basis has it (its 3-2-1 position; :mod:`lacore.reconstruction.context`); a component where that face is
        degenerate stays where it is."""
        if self._place_frames is None:
            return X
        out = None
        for face, (o_ref, Q_ref), idx in self._place_frames:
            try:
                o, Q = triangle_frame(X, face)
            except MeshError:
                continue
            M = Q.T @ Q_ref
            Y = X @ M if idx is None else X[idx] @ M
            for j, tj in enumerate(o_ref - o @ M):          # one column at a time: faster than broadcasting (3,)
                Y[:, j] += tj
            if idx is None:
                return Y
            out = X.copy() if out is None else out
            out[idx] = Y
        return X if out is None else out

    def _output_basis(self):
        """``X = y0 + B q`` in the caller's frame and units (the context's affine map from canonical coordinates)."""
        ctx, U = self._context, self.basis
        V, r = self.n_vertices, U.shape[1]
        self._y0 = ctx.from_canonical(self._key_x[0].reshape(-1, 3))
        zero = ctx.from_canonical(np.zeros((V, 3)))
        B = np.empty((V, 3, r))
        Ur = U.reshape(V, 3, r)
        for j in range(r):
            B[:, :, j] = ctx.from_canonical(Ur[:, :, j]) - zero
        self._B = B.reshape(3 * V, r)

    def _make_energy(self, edges, c, metric=None, basis=None):
        """The reduced energy on ``edges`` with cubature weights ``c`` in the space of ``basis`` (default the mixer's
        own); with ``metric`` ``M`` on the basis ``U M^T``."""
        P = self._problem
        U = self.basis if basis is None else basis
        if metric is not None:
            U = U @ metric.T
        return ReducedEnergy(self._stencils, self._key_x[0], U, P.w, P.z0, P.dz, P.floor, edges, c)

    def _screening_sample(self):
        """``(edges, weights)`` of the screening: a seeded random sample of :data:`SCREENING_EDGES` edges, each
        weighted by the number of edges over the sample's size (``(None, None)``, all edges at weight 1, on smaller
        meshes); drawn once per mixer."""
        if self._screening is None:
            E = self.n_edges
            if E <= SCREENING_EDGES:
                self._screening = None, None
            else:
                edges = np.sort(np.random.default_rng(0).choice(E, SCREENING_EDGES, replace=False))
                self._screening = edges, np.full(SCREENING_EDGES, E / SCREENING_EDGES)
        return self._screening

    def _screening_energy(self):
        """The reduced energy on the screening's sample of edges (:meth:`_screening_sample`): its minimizers stand in
        for the exact ones in the space where :func:`.subspace.space_indicator` ranks the exploration weights, and
        they are the cubature's training points at its added weights (:meth:`_fit_cubature`)."""
        return self._make_energy(*self._screening_sample())

    @staticmethod
    def _screened(energy, w, q0):
        """The minimizer ``(r,)`` of a screening energy (:meth:`_screening_energy`) at the weights ``w``, from ``q0``:
        at most :data:`SCREENING_ITERATIONS` Gauss-Newton steps, stopping at :data:`SCREENING_FTOL`."""
        return energy.solve(w, q0, SCREENING_ITERATIONS, ftol=SCREENING_FTOL)[0]

    def _presolve(self, U, w, q0):
        """``q0`` moved by :data:`PRESOLVE_ITERATIONS` Gauss-Newton steps of the reduced energy of the basis ``U`` (the
        space the Newton vectors have grown so far) on the screening's sample of edges, at the weights ``w``."""
        return self._make_energy(*self._screening_sample(), basis=U).solve(w, q0, PRESOLVE_ITERATIONS)[0]

    def _cubature_samples(self):
        """Training points ``(weights (S, m), q (S, r))``: the points the build solved and Taylor predictions at
        fixed and seeded random weights."""
        m = self.n_keys - 1
        o = self.options
        rng = np.random.default_rng(1)
        extra = [np.full(m, 0.25), np.full(m, 0.75)] + list(rng.uniform(o.low, o.high, (3 * m, m)))
        extra += list(rng.uniform(0.0, 1.0, (3 * m, m)))
        W = np.concatenate([self._exp_w, np.array(extra)])
        Q = np.concatenate([self._exp_q, np.array([self.predict(wk) for wk in extra])])
        return W, Q

    def _training(self, samples, metrics=False, energies=None, energy_weights=None, densities=None):
        """Exact gradient pieces ``(m+1, r)`` at every sample (sparse products with the full Jacobian) and a score per
        edge bounding the size of its pieces; with ``metrics`` also ``C^{-1}`` ``(r, r)``, ``C C^T`` the reduced
        Gauss-Newton matrix ``2 U^T J^T W J U`` at the first sample (the energy norm of
        :func:`.cubature.fit_cubature`; the matrix of each sample instead costs a product ``J U`` per sample, 0.6 s
        more at 13k vertices, for the same energies on the 13k bodies).  The build's own Jacobians at the keys and
        the Newton points are not kept for it: holding their terms through the Newton stage cost more there (page
        faults) than the 16 Jacobians saved here (docs/shape-space.md).

        ``energies``: a list that receives the full energy at every sample for the weights ``energy_weights[i]``;
        ``densities`` a list that receives at every sample the space's error density for those weights
        (:func:`.local.space_error_density`, the local correction's choice)."""
        P, U, topo = self._problem, self.basis, self.topology
        E = self.n_edges
        x0 = self._key_x[0]
        un = np.sqrt((U.reshape(-1, 3, U.shape[1]) ** 2).sum(axis=(1, 2)))        # per-vertex norm of U
        st = self._stencils
        reach = np.concatenate([np.sqrt(un[st[:, 0]] ** 2 + un[st[:, 1]] ** 2), np.sqrt((un[st] ** 2).sum(axis=1))])
        abs_wdz = np.abs(P.weighted_dz)                                             # |C| but its first column
        totals, score = [], np.zeros(2 * E)
        inverse_factor = vertex_scale = None
        gradients = []
        for i, q in enumerate(samples):
            J, z = lengths_and_angles_jacobian((x0 + U @ q).reshape(-1, 3), topo, return_z=True)
            if energies is not None:
                energies.append(P.energy_z(z, energy_weights[i]))
            JtC, rown, c0 = P.training_terms(J, z)
            totals.append(JtC.T @ U)                        # (m+1, r); U^T JtC runs about half as fast
            if densities is not None:
                if vertex_scale is None:      # a third of the trace of each vertex's block of J^T W J, once
                    dof = np.bincount(J.indices, weights=J.data ** 2 * np.repeat(P.w, np.diff(J.indptr)),
                                      minlength=J.shape[1])
                    vertex_scale = 2.0 * dof.reshape(-1, 3).sum(axis=1) / 3.0
                g = 2.0 * (JtC[:, 0] - JtC[:, 1:] @ np.asarray(energy_weights[i], float))  # J^T W r = J^T C [1, -w]
                g[P.fixed] = 0.0
                gradients.append(g)
            if metrics and i == 0:
                H = 2.0 * reduced_normal_equations(J, U, np.sqrt(P.w))[0]
                H[np.diag_indices_from(H)] += 1e-12 * np.trace(H) / len(H)
                inverse_factor = sl.solve_triangular(np.linalg.cholesky(H), np.eye(len(H)), lower=True,
                                                     check_finite=False)
            # bound of the pieces of row j in column k of C: |C_jk| t_j, t = row norm of J times the reach of U there,
            # normalized by its sum over the rows (every column counts alike)
            t = rown * reach
            a0 = np.abs(c0)
            sums = np.maximum(np.r_[t @ a0, t @ abs_wdz], 1e-300)
            score += t * (a0 / sums[0] + abs_wdz @ (1.0 / sums[1:]))
        score = score[:E] + score[E:]
        if gradients:
            densities.extend(space_error_density(np.stack(gradients, axis=1), U, vertex_scale))
        if metrics:
            return totals, score, inverse_factor
        return totals, score

    def _fit_cubature(self):
        r = self.basis.shape[1]
        E = self.n_edges
        n = self.options.cubature_points or max(300, (20 if self._derivatives else 12) * r)
        self._corr_w = self._corr = None
        if E <= 2 * n:
            self._cubature = self._make_energy(None, None)
            self.cubature_residual = 0.0
            return
        W, Q = self._cubature_samples()
        # the added weights at the space's minimizers, where the mixes' minimizers lie: those of the reduced energy on
        # the screening's sample of edges, from the Taylor predictions (one reduced Gauss-Newton step with the full
        # Jacobian instead cost 0.2 s more at 13k vertices and 0.9 s more at 50k, for the same energies or worse:
        # docs/shape-space.md)
        n_built = len(self._exp_w)
        sampled = self._screening_energy()
        Q = list(Q[:n_built]) + [self._screened(sampled, wk, qk)
                                 for wk, qk in zip(W[n_built:], Q[n_built:], strict=True)]
        energies, densities = [], []
        if self.options.cubature_energy_norm:
            totals, score, metrics = self._training(Q, metrics=True, energies=energies, energy_weights=W,
                                                    densities=densities)
        else:
            (totals, score), metrics = self._training(Q, energies=energies, energy_weights=W,
                                                      densities=densities), None
        self._set_local(hot_vertices(densities, self.options.local_vertices))
        Q = np.array(Q)
        # with the energy norm, also the whole gradient at every sample's own weights (relative to its energy)
        edges, c, rel = fit_cubature(self._make_energy, list(Q), totals, score, n, metric=metrics,
                                     weights=None if metrics is None else W, energies=np.array(energies))
        self._cubature = self._make_energy(edges, c)
        self.cubature_residual = rel
        if not self.options.cubature_correction:
            return
        # gradient corrections at the cubature's own minimizers of the training weights
        cub = self._cubature
        step_tol = self.options.step_tolerance * self._context.size * np.sqrt(self.n_vertices)
        Qs = np.array([cub.solve(wk, qk, self.options.max_iterations, step_tol)[0]
                       for wk, qk in zip(W, Q, strict=True)])
        exact, _ = self._training(list(Qs))
        self._corr_w = W
        self._corr = np.array([t - cub.gradient_pieces(q).sum(axis=2) for t, q in zip(exact, Qs, strict=True)])

    def _set_local(self, hot):
        """The local correction on the vertices ``hot`` (none when empty)."""
        self._local = None
        if not len(hot):
            return
        ctx, V = self._context, self.n_vertices
        zero = ctx.from_canonical(np.zeros((V, 3)))
        linear = np.stack([ctx.from_canonical(np.tile(e, (V, 1))) - zero for e in np.eye(3)], axis=2)
        self._local = LocalCorrection(self.topology, hot, self._key_x[0], self.basis, self._problem,
                                      ctx.fixed_dofs, linear)

    @property
    def local_vertices(self):
        """The vertices the local correction moves (:mod:`.local`), an int array (empty: none)."""
        return np.zeros(0, np.int64) if self._local is None else self._local.hot.copy()

    def _shift(self, w):
        """Gradient correction ``(r,)`` of the cubature at the weights ``w`` (None without cubature): the difference
        between the exact and the cubature's gradient pieces at the training minimizers, interpolated by inverse
        squared distances in weight space; it makes the cubature's gradient exact at the training minimizers."""
        if self._corr_w is None:
            return None
        d2 = ((self._corr_w - w) ** 2).sum(axis=1)
        i = int(np.argmin(d2))
        if d2[i] <= 1e-24:
            phi = np.zeros(len(d2))
            phi[i] = 1.0
        else:
            phi = d2 ** -_CORRECTION_POWER
            phi /= phi.sum()
        pieces = np.einsum("s,skr->kr", phi, self._corr)                  # (m+1, r)
        return pieces[0] - w @ pieces[1:]

    # ------------------------------------------------------------------ properties
    @property
    def n_keys(self):
        """K, the number of keys (the basis included)."""
        return self.keys.shape[0]

    @property
    def n_vertices(self):
        return self.keys.shape[1]

    @property
    def derived_keys(self):
        """``(K-1,)`` bool: the keys whose blend at weight 1 alone is not the key itself (a mask below 1 somewhere, or
        another relative key than the basis; ``masks``, ``relative_to`` of :meth:`build`)."""
        return self._derived.copy()

    @property
    def reduced_size(self):
        """Size ``r`` of the reduced space."""
        return int(self.basis.shape[1])

    @property
    def cubature_size(self):
        """Number of edges of the energy a mix evaluates."""
        return int(len(self._cubature.edges))

    @property
    def nbytes(self):
        """Memory of the reduced model (basis, output basis, cubature), in bytes."""
        cub = self._cubature
        local = 0 if self._local is None else self._local.nbytes
        return int(self.basis.nbytes + self._B.nbytes + 2 * cub.US.nbytes + cub.xb.nbytes + self._exp_T.nbytes
                   + local)

    # ------------------------------------------------------------------ mixing
    def check_weights(self, weights):
        """``weights`` as a finite ``(K-1,)`` float array, or :class:`MixerError`."""
        try:
            w = np.asarray(weights, float)
        except (TypeError, ValueError):
            raise MixerError(f"weights must be {self.n_keys - 1} numbers, one per non-basis key") from None
        if w.shape != (self.n_keys - 1,):
            raise MixerError(f"weights must be {self.n_keys - 1} numbers, one per non-basis key, got shape "
                             f"{w.shape}")
        if not np.all(np.isfinite(w)):
            raise MixerError(f"weights must be finite numbers, got {w.tolist()}")
        return w

    def target(self, weights):
        """The blended lengths and angles ``z(w)`` ``(2E,)`` (:func:`blend_targets` with the mixer's masks and
        relative keys)."""
        return _blend(self.z_keys[0], self._directions, self.check_weights(weights), self.n_edges, MIN_LENGTH_RATIO)

    def range_message(self, weights, names=None, advice=None):
        """``""`` when ``weights`` lie in the accurate range, else one line saying which do not.

        ``names``: the non-basis keys' names for the message (default ``key 1``, ``key 2`` ...); ``advice``:
        what to do, ending the line (default: polish or rebuild with a wider range, in lacore's and the CLI's
        terms).

        Examples
        --------
        >>> import numpy as np
        >>> from lacore.samples.bar import bar_mesh, bar_pose
        >>> X, faces = bar_mesh(n_along=4, n_side=1)
        >>> mixer = ShapeMixer.build([X, bar_pose(X, 0.6, 0.0), bar_pose(X, 0.0, 0.6)], faces)
        >>> message = mixer.range_message([2.0, 0.5], names=["Bend", "Twist"], advice="keep the sliders in range")
        >>> message.split(":")[0], message.endswith("; keep the sliders in range")
        ('weights outside [-0.5, 1.5] (Bend = 2)', True)
        """
        w = np.asarray(weights, float)
        lo, hi = self.options.low, self.options.high
        out = np.flatnonzero((w < lo) | (w > hi))
        if not out.size:
            return ""
        label = [f"key {i + 1}" for i in range(len(w))] if names is None else [str(n) for n in names]
        which = ", ".join(f"{label[i]} = {w[i]:g}" for i in out[:4])
        if advice is None:
            advice = ("polish it for the exact projection (polish=True, lacore mix --polish) or rebuild the mixer "
                      "with a wider range (MixerOptions low/high, lacore mixer --range)")
        return (f"weights outside [{lo:g}, {hi:g}] ({which}): the mix extrapolates beyond the range the mixer "
                f"was built for; {advice}")

    def full_energy(self, weights, vertices):
        """``W_q[z(w), Z(vertices)]`` on the whole mesh (the energy the full projection minimizes)."""
        return float(self._context.energy(self.target(weights), vertices))

    def predict(self, weights, order=2):
        """Taylor prediction ``(r,)`` of the reduced coordinates from the nearest expansion point."""
        w = np.asarray(weights, float)
        near = self._nearest(w, order)
        d = w - self._exp_w[near]
        q = self._exp_q[near] + self._exp_A[near] @ d
        if order >= 2 and self._exp_order[near] >= 2:
            q = q + 0.5 * np.einsum("a,b,abr->r", d, d, self._exp_T[near])
        return q

    def _start(self, w):
        """A start for the reduced minimizer at ``w``: the point the build solved there, else the Taylor prediction."""
        i = self._nearest(w)
        return self._exp_q[i].copy() if np.abs(self._exp_w[i] - w).max() <= 1e-12 else self.predict(w)

    def _nearest(self, w, order=0):
        dist = np.abs(self._exp_w - w).sum(axis=1)
        if order > 0:
            dist = np.where(self._exp_order >= 1, dist, np.inf)
        return int(np.argmin(dist))

    def relative_size(self, weights):
        """The size the distances of a mix are relative to, as a multiple of the basis' bounding-box diagonal.

        The total edge length of the blend ``z(w)`` over the basis' (linear in the weights: ``1 + sum_k w_k
        (L_k / L_0 - 1)`` for total lengths ``L_k`` of the keys, held at least :data:`MIN_LENGTH_RATIO`, the floor
        of every blended length; with masks or relative keys ``L_k - L_0`` is the total length of the key's
        direction, :func:`key_directions`): 1 wherever the keys are poses of one size, ``s`` at weight 1 of a key
        scaled by ``s``, whatever the poses; ``O(K)`` per call.  Distances over the basis' diagonal divided by it are
        distances over the blend's own size.  The indicators of :meth:`indicator` and of
        :func:`lacore.shapes.mixing.path_inbetweens` are relative to it.

        Parameters
        ----------
        weights : (K-1,) or (N, K-1) array_like

        Returns
        -------
        float or (N,) ndarray

        Examples
        --------
        >>> from lacore.samples.bar import bar_mesh, bar_pose
        >>> X, faces = bar_mesh(n_along=4, n_side=1)
        >>> mixer = ShapeMixer([X, 0.1 * bar_pose(X, 0.4, 0.0)], faces)
        >>> mixer.relative_size([[0.0], [0.5], [1.0]]).round(3).tolist()
        [1.0, 0.55, 0.1]
        """
        w = np.asarray(weights, float)
        size = np.maximum(1.0 + w @ self._length_gains, MIN_LENGTH_RATIO)
        return float(size) if size.ndim == 0 else size

    def indicator(self, weights):
        """Estimated RMS error of the mix, relative to its own size (the basis' bounding-box diagonal times
        :meth:`relative_size`).

        The build measures the error of the space at the candidate weights (the RMS length of the
        last round's Newton vectors, :func:`.subspace.newton_vectors`, before they join the space: an
        upper estimate; over the basis' diagonal) and knows it is 0 at the keys; this interpolates those
        values by inverse squared distances in weight space and divides by :meth:`relative_size` at
        ``weights``.  Without Newton vectors: NaN.
        """
        if self._error_w is None:
            return float("nan")
        w = self.check_weights(weights)
        d2 = ((self._error_w - w) ** 2).sum(axis=1)
        i = int(np.argmin(d2))
        if d2[i] <= 1e-24:
            error = float(self._error_v[i])
        else:
            inv = 1.0 / d2
            error = float(inv @ self._error_v / inv.sum())
        return error / self.relative_size(w) if error else error

    def mix(self, weights, *, warm_start=True, polish=False):
        """The mix for ``weights`` ``(K-1,)``: the projection of ``z(w)``.

        Parameters
        ----------
        weights : (K-1,) array_like
            One weight per non-basis key (the slider values); outside ``[low, high]`` they extrapolate.
        warm_start : bool
            Start from the previous mix when its reduced energy is below that of the Taylor prediction
            of the nearest key (the start otherwise).
        polish : bool
            Finish with the full Gauss-Newton projection from the reduced result (the exact mix).

        Returns
        -------
        MixResult
        """
        t0 = time.perf_counter()
        w = self.check_weights(weights)
        cub = self._cubature
        step_tol = self.options.step_tolerance * self._context.size * np.sqrt(self.n_vertices)
        with np.errstate(over="ignore", invalid="ignore"):     # weights too large for float64: refused below
            shift = self._shift(w)
            q0 = self.predict(w)
            if (warm_start and self._last_q is not None
                    and cub.energy(self._last_q, w, shift) < cub.energy(q0, w, shift)):
                q0 = self._last_q
            q, energy, its = cub.solve(w, q0, self.options.max_iterations, step_tol, shift=shift)
            X = (self._y0.ravel() + self._B @ q).reshape(-1, 3)
            if self._local is not None:
                dX, change = self._local.step(q, w)
                X[self._local.hot] += dX
                energy += change
        if not (np.isfinite(energy) and np.all(np.isfinite(X))):
            raise MixerError(f"the mix of weights {w.tolist()} overflows float64: weights this far outside "
                             f"[{self.options.low:g}, {self.options.high:g}] cannot be blended; use smaller ones")
        self._last_q = q
        indicator = self.indicator(w)
        msg = self.range_message(w)
        if not msg and indicator > self.options.max_indicator:
            advice = "" if polish else "; polish it for the exact projection (polish=True, lacore mix --polish)"
            msg = (f"error indicator {indicator:.3g} above {self.options.max_indicator:g}: the reduced mix may be "
                   f"off{advice}")
        polished = False
        if polish:
            try:
                res = reconstruct(self.target(w), self.topology, self.keys[0], context=self._context,
                                  options=self._gn, initial_vertices=X)
            except LengthsAnglesError as exc:  # a blend no mesh comes near (most faces break the triangle inequality)
                msg = (msg + "; " if msg else "") + f"no full projection: {exc}; the reduced mix is returned"
            else:
                X, energy, its, polished = res.vertices, float(res.energy), its + int(res.iterations), True
                if res.success:
                    msg = ""
                else:
                    msg = (msg + "; " if msg else "") + f"the full projection did not converge ({res.message})"
        return MixResult(vertices=self._place(X), weights=w, energy=float(energy), indicator=indicator,
                         in_range=not msg, message=msg, seconds=time.perf_counter() - t0, iterations=int(its),
                         polished=polished)

    # ------------------------------------------------------------------ files
    def save(self, path):
        """Write the mixer to ``path`` (``.npz`` appended unless it ends so), atomically; returns the path
        (the layout: :mod:`.files`)."""
        m, r = self.n_keys - 1, self.reduced_size
        return write_mixer_file(path, {
            "keys": self.keys, "faces": self.faces, "options": self.options.to_array(), "basis": self.basis,
            "masks": self.masks, "relative_to": self.relative_to, "corners": self._corners,
            "cubature_edges": self._cubature.edges, "cubature_weights": self._cubature.c,
            "expansion_weights": self._exp_w, "expansion_q": self._exp_q, "expansion_order": self._exp_order,
            "expansion_first": self._exp_A, "expansion_second": self._exp_T,
            "indicator_weights": np.zeros((0, m)) if self._error_w is None else self._error_w,
            "indicator_values": np.zeros(0) if self._error_v is None else self._error_v,
            "correction_weights": np.zeros((0, m)) if self._corr_w is None else self._corr_w,
            "correction": np.zeros((0, m + 1, r)) if self._corr is None else self._corr,
            "local_vertices": self.local_vertices, "fixed_faces": self._context.fixed_faces,
            "build_stages": np.array(list(self.build_seconds), dtype=str),
            "build_seconds": np.array(list(self.build_seconds.values()), float)})

    @classmethod
    def load(cls, path):
        """Read a mixer written by :meth:`save`; :class:`MixerError` naming the file for anything else (not a
        mixer, another format version, arrays that do not fit together or are not finite)."""
        name = os.fspath(path) if isinstance(path, (str, os.PathLike)) else str(path)
        a = read_mixer_file(path, MixerError)
        try:
            keys, topology = check_keys(a["keys"], a["faces"])
            corners = keys if a["corners"] is None else a["corners"]
            if corners.shape != keys.shape or not np.all(np.isfinite(corners)):
                raise MixerError(f"'corners' has shape {corners.shape}, expected {keys.shape}, or is not finite")
            fixed = a["fixed_faces"] if a["fixed_faces"] is not None else _basis_fixed_faces(a["basis"], topology)
            mixer = cls(keys, a["faces"], MixerOptions.from_array(a["options"]), masks=a["masks"],
                        relative_to=a["relative_to"], _topology=topology, _corners=corners, _fixed_faces=fixed)
        except InputError as exc:
            raise MixerError(f"{name} is not a valid shape mixer: {exc}") from None
        U, edges, c, hot = a["basis"], a["cubature_edges"], a["cubature_weights"], a["local_vertices"]
        V, m = mixer.n_vertices, mixer.n_keys - 1
        r, P = U.shape[1], len(a["expansion_weights"])
        n_ind, n_corr = len(a["indicator_values"]), len(a["correction"])
        expect = {"basis": (3 * V, r), "cubature_weights": edges.shape, "expansion_weights": (P, m),
                  "expansion_q": (P, r), "expansion_order": (P,), "expansion_first": (P, r, m),
                  "expansion_second": (P, m, m, r), "build_seconds": a["build_stages"].shape,
                  "indicator_weights": (n_ind, m), "correction_weights": (n_corr, m), "correction": (n_corr, m + 1, r)}
        for key, want in expect.items():
            if a[key].shape != want:
                raise MixerError(f"{name}: '{key}' has shape {a[key].shape}, expected {want}: the file is damaged; "
                                 "rebuild the mixer")
        bad = [k for k in ("basis", "cubature_weights", "expansion_weights", "expansion_q", "expansion_first",
                           "expansion_second", "indicator_weights", "indicator_values", "correction_weights",
                           "correction") if not np.all(np.isfinite(a[k]))]
        if P == 0:  # (every mix starts from an expansion point)
            bad.append("expansion_weights")
        if len(hot) and (hot.min() < 0 or hot.max() >= V or np.any(np.diff(hot) <= 0)):
            bad.append("local_vertices")
        if np.any(U[mixer._context.fixed_dofs] != 0):       # coordinates of other fixed faces
            bad.append("fixed_faces")
        if bad or r < 1 or edges.size == 0 or edges.min() < 0 or edges.max() >= mixer.n_edges or np.any(c < 0):
            raise MixerError(f"{name}: the reduced model is damaged ({', '.join(bad) or 'cubature'}); rebuild the "
                             "mixer")
        mixer.basis = np.ascontiguousarray(U)
        mixer._exp_w, mixer._exp_q, mixer._exp_order = a["expansion_weights"], a["expansion_q"], a["expansion_order"]
        mixer._exp_A, mixer._exp_T = a["expansion_first"], a["expansion_second"]
        mixer._output_basis()
        if n_ind:
            mixer._error_w, mixer._error_v = a["indicator_weights"], a["indicator_values"]
        if n_corr:
            mixer._corr_w, mixer._corr = a["correction_weights"], a["correction"]
        mixer._cubature = mixer._make_energy(edges, c)
        mixer._set_local(hot)
        mixer.build_seconds = dict(zip(a["build_stages"].tolist(), a["build_seconds"].tolist(), strict=True))
        return mixer


def _basis_fixed_faces(U, topology):
    """The faces a basis ``U`` ``(3V, r)`` holds still (one per component at most, the lowest index): those whose
    3-2-1 coordinates (``a.xyz, b.yz, c.z``, :mod:`lacore.reconstruction.context`) are 0 in every vector; None for
    an array of another shape."""
    if U.ndim != 2 or U.shape[0] != 3 * topology.n_vertices:
        return None
    zero = np.all(U == 0, axis=1).reshape(-1, 3)
    a, b, c = topology.faces.T
    hit = np.flatnonzero(zero[a].all(axis=1) & zero[b, 1] & zero[b, 2] & zero[c, 2])
    labels = topology.face_components()[1][hit]
    return hit[np.unique(labels, return_index=True)[1]]


def mixer_bytes(mixer):
    """The file :meth:`ShapeMixer.save` writes for ``mixer``, as bytes (``ShapeMixer.load(io.BytesIO(data))`` reads
    it)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = mixer.save(os.path.join(tmp, "mixer.npz"))
        with open(path, "rb") as fh:
            return fh.read()


def build_mixer_bytes(keys, faces, options=None, *, masks=None, relative_to=None, names=None, progress=None):
    """:meth:`ShapeMixer.build` returning :func:`mixer_bytes`: what crosses a process boundary
    (:func:`lacore.parallel.call_in_process`; a built mixer holds sparse factorizations, which do not pickle)."""
    return mixer_bytes(ShapeMixer.build(keys, faces, options, masks=masks, relative_to=relative_to, names=names,
                                        progress=progress))
