"""What each reproduction page shows (`PAPERS`: its rows, figures and what differs in the
data, written down here, never typed into a page) and how the pages print a number
(`fmt`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

from fxspace.pipelines._registry import experiments_of


@dataclass(frozen=True)
class Row:
    """One line of a paper's table: ``label``, the paper's number (``None``: the paper
    gives none), where ours is (``config``, a dotted ``path`` into its metrics; ``mean``
    reduces a list) and a ``note`` (what differs)."""

    label: str
    paper: float | str | None
    config: str
    path: str
    note: str = ""
    mean: bool = False


@dataclass(frozen=True)
class Paper:
    """A reproduction page. Its experiments are not listed here: they are the pipelines
    that declare ``REPRODUCTION = <this page's key>`` (`configs`, read off the registry)."""

    title: str
    source: str
    rows: tuple[Row, ...]
    figures: tuple[tuple[str, str, str], ...]  # (config, file in its run folder, caption)
    differs: str
    intro: str = ""
    extra: tuple[str, ...] = field(default=())
    key: str = ""

    @property
    def configs(self) -> tuple[str, ...]:
        """The shipped configs this page reads: every experiment whose pipeline declares
        ``REPRODUCTION`` = this page's key (`fxspace.pipelines._registry.experiments_of`)."""
        return experiments_of(self.key)


_FIG3_ROWS = (  # Ha & Han Fig. 3 read off the joints (metric suffix, label, note)
    ("unaligned", "clocks apart (a)", "a 60-s scripted session, each body half on its own "
     "clock; the paper shows it (Fig. 3a) and prints no number"),
    ("aligned_as_printed", "aligned, eqs. 2–3 as printed (b)", "max_clock_rate = inf, α = ½"),
    ("aligned", "aligned, eqs. 2–3 bounded (default)", "each clock at most its set's "
     "fastest example at that phase"),
    ("examples", "the captured takes", "the same measure on every take of the set-up"),
)  # fmt: skip
_FIG5_ROWS = (  # Ha & Han §3.2, Fig. 5: re-placement against stale samples
    ("upper samples' error, stale (not re-placed)", "stale_sample_error_mean_m",
     "mean distance to exactly re-sampled parameters after a lower-body change; the "
     "paper shows Fig. 5 (\"approximated without large error\") and prints no number"),
    ("upper samples' error, re-placed (Horn rotation from k samples)",
     "replacement_error_mean_m", "lower is better: re-placement should cut the stale error"),
    ("hand target error over stale samples", "upper_target_error_stale_mean_m",
     "k-NN blend aimed at a reachable hand target, then measured"),
    ("hand target error over re-placed samples", "upper_target_error_replaced_mean_m", ""),
)  # fmt: skip

PAPERS: dict[str, Paper] = {
    "kim-jung": Paper(
        title="Kim & Jung: the expression space and its navigation",
        source="../shared/papers/000_5ac3516e1e4af788.txt",
        intro="AnimFace's 2 400 frames × 41 markers, the state the whole marker-distance "
        "matrix (mm), ε chosen by the paper's rule (the highest Pearson r over a sweep).",
        rows=(
            Row(
                "ε chosen (mm)",
                230.0,
                "navigation",
                "threshold",
                "the paper's capture has 100 markers, ours 41: only the order compares",
            ),
            Row("Pearson r at ε", 0.9647, "navigation", "r"),
            Row(
                "levels of the hierarchy",
                "9 (≈10 · 2⁸ ≥ 2 400)",
                "navigation",
                "num_levels",
                "the paper prints no count: ≈10 centres at the first level, the count "
                "doubled at every level, all ≈2 400 frames at the last (§4.1, §5)",
            ),
            Row(
                "ρ scale chosen by the link-radius experiment (× centre spacing)",
                None,
                "navigation",
                "rho_experiment.chosen_scale",
                "the paper finds ρ by experiment and gives no value; ours: the largest "
                "scale that keeps the levels up to 320 centres connected by the rule alone",
            ),
            Row(
                "links added outside the paper's rule (bridges)",
                0,
                "navigation",
                "links_bridged",
                "the rule alone by default (hierarchy.bridges = false); the paper adds none",
            ),
            Row(
                "pieces the links leave the finest level in",
                None,
                "navigation",
                "link_pieces_finest",
                "centres closer than ρ to another can only link to that one; the paper "
                "shows links only at its ~10-centre level",
            ),
            Row(
                "route: consecutive frames are neighbours in the frame graph",
                None,
                "navigation",
                "path_is_graph_walk",
                "the paper joins the animator's key frames along the links between "
                "neighbouring centres (§4.2) and says nothing of the frames between them",
            ),
        ),
        figures=(
            ("navigation", "r_vs_threshold.png", "Pearson r against ε (the sweep)"),
            ("navigation", "levels_grid.png", "the levels of the hierarchy and the route"),
            (
                "navigation",
                "link_radius.png",
                "links and coverage against ρ: the experiment that chooses ρ",
            ),
        ),
        differs="AnimFace (41 markers, one performer) stands in for the paper's 100-marker "
        "capture; the state distance and the ε rule are the paper's.",
    ),
    "hirose-higuchi": Paper(
        title="Hirose & Higuchi: control points of a dense face",
        source="../shared/papers/004_96e90575cb94c762.txt",
        intro="AnimFace cheeks, frames 300–599 thinned to 150 as in the paper; the dense "
        "face is the markers' RBF surface (≈ 6 000 vertices, as the paper's 6 331) and, "
        "beside it, the solved ICT head's 9 409 face vertices.",
        rows=(
            Row(
                "frames of the compared segment",
                43,
                "reconstruction",
                "paper_segment.n_frames",
                "ours: the fused-lasso segment closest to 43 frames",
            ),
            Row(
                "linear interpolation, eq. (1)",
                16.44,
                "reconstruction",
                "paper_segment.linear_error",
                "eq. (1) sums squared mm over vertices and "
                "frames: the magnitudes depend on the surface, the ratio compares",
            ),
            Row("control points, eq. (1)", 1.82, "reconstruction", "paper_segment.ours_error"),
            Row(
                "ratio ours / linear (that segment)",
                0.111,
                "reconstruction",
                "error_ratio_paper_segment",
            ),
            Row(
                "ratio, whole scene (RBF surface)", None, "reconstruction", "error_ratio_scene_rbf"
            ),
            Row(
                "ratio, whole scene (ICT head vertices)",
                None,
                "reconstruction",
                "error_ratio_scene_head",
            ),
            Row(
                "segments",
                8,
                "reconstruction",
                "n_segments_chosen",
                "ours chosen from the data (elbow of the fused-lasso path)",
            ),
            Row(
                "whole-scene pipeline time (s)",
                18.0,
                "reconstruction",
                "scene_pipeline_time_s",
                "the paper's machine is not ours",
            ),
            Row("head marker residual, solved (mm)", None, "reconstruction", "head.residual_mean"),
            Row(
                "head marker residual, rigid only (mm)",
                None,
                "reconstruction",
                "head.residual_rigid_only_mean",
            ),
        ),
        figures=(
            ("reconstruction", "reconstruction.png", "original, linear and ours"),
            ("reconstruction", "segmentation.png", "the fused-lasso segmentation"),
            ("reconstruction", "scene_errors.png", "eq. (1) per segment"),
        ),
        differs="The paper's face is 6 331 vertices from a dense capture; ours is driven by "
        "41 markers (RBF) or solved from them (the ICT head), so its motion between the "
        "markers is smoother than a dense capture's.",
    ),
    "ha-han": Paper(
        title="Ha & Han: decoupled parametric motion",
        source="../shared/papers/002_fec3f42589414a0d.txt",
        intro="The three set-ups of Table 1 on Bandai Namco and CMU clips.",
        rows=tuple(
            r
            for s in ("mood_walk", "block_walk", "block_kick")
            for r in (
                Row(
                    f"{s}: upper / lower examples (Table 1)",
                    {"mood_walk": "2 / 10", "block_walk": "12 / 12", "block_kick": "12 / 11"}[s],
                    "parametric_synthesis",
                    f"{s}.table1.ours_upper_lower",
                    "the CMU takes hold 7 clean right kicks" if s == "block_kick" else "",
                ),
                *(
                    Row(
                        f"{s}: Fig. 3, arm swing / stride cycle length, {lab}",
                        None,
                        "parametric_synthesis",
                        f"{s}.fig3_cycle_ratio_{k}",
                        note,
                    )
                    for k, lab, note in _FIG3_ROWS
                    if s != "block_kick"
                ),
                *(
                    Row(
                        f"{s}: Fig. 3, arm-swing phase drift against the strides "
                        f"(cycles/min), {lab}",
                        None,
                        "parametric_synthesis",
                        f"{s}.fig3_phase_drift_{k}",
                        note,
                    )
                    for k, lab, note in _FIG3_ROWS
                    if s != "block_kick"
                ),
                *(
                    Row(
                        f"{s}: §3.2 (Fig. 5), {lab} (m)",
                        None,
                        "parametric_synthesis",
                        f"{s}.{path}",
                        note,
                    )
                    for lab, path, note in _FIG5_ROWS
                    if s != "mood_walk"
                ),
                Row(f"{s}: synthesis step (ms)", None, "parametric_synthesis", f"{s}.step_ms"),
            )
        ),
        figures=(
            (
                "parametric_synthesis",
                "mood_walk_fig3.png",
                "Fig. 3 read off the joints, mood walk: the arm swing's phase at each stride "
                "over a 60-s session, clocks apart (a) and aligned (b)",
            ),
            (
                "parametric_synthesis",
                "block_walk_fig3.png",
                "Fig. 3 read off the joints, block walk",
            ),
            (
                "parametric_synthesis",
                "block_walk_replacement.png",
                "§3.2 (Fig. 5), block walk: upper samples stale, re-placed and re-sampled",
            ),
        ),
        differs="Bandai Namco's and CMU's clips stand in for the paper's captures; the "
        "paper's Table 1 counts are matched where the clips allow.",
    ),
    "park-kang-kwon": Paper(
        title="Park, Kang & Kwon: mesh IK with the factored gradient",
        source="../shared/papers/003_8b82dd8ad91a5214.txt",
        intro="The shipped skinned glTF models, markers on visible triangles.",
        rows=(
            Row(
                "naive / factored, per solved frame (BFGS on eq. 9 vs eq. 13, CesiumMan, cold)",
                3.14,
                "mesh_ik",
                "paper_comparison.ratio_per_solved_frame_cold",
                "as the paper: every frame solved from rest, time per frame; the paper's "
                "human model is not shipped, CesiumMan stands in",
            ),
            Row(
                "naive / factored, per gradient evaluation (mean over the five models)",
                None,
                "mesh_ik",
                "models.per evaluation",
                "not the paper's measure: one gradient call in a jitted loop, models "
                "including a synthetic 48-joint chain (see the benchmark page)",
                mean=True,
            ),
        ),
        figures=(
            ("mesh_ik", "models_speedup.png", "Fig. 9: speed-up per model"),
            ("mesh_ik", "models_time_vs_markers.png", "Fig. 10: time per frame vs markers"),
        ),
        differs="The paper's human models are not shipped; the glTF samples (CesiumMan, Fox, "
        "RiggedSimple…) stand in, with fewer joints.",
    ),
}
PAPERS = {k: replace(p, key=k) for k, p in PAPERS.items()}  # each page knows its key


def fmt(v: Any) -> str:
    """A number as the pages print it (4 significant digits; booleans as yes/no)."""
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        return f"{v:.4g}"
    if isinstance(v, list | tuple):
        return " / ".join(fmt(x) for x in v)
    return str(v)
