"""What each registration metric means and what a good value looks like.

One source for the app's Metrics dock (names and tooltips) and the HTML report (its
table of metrics with their meaning). No Qt.
"""

from __future__ import annotations

# (key, name, kind, tooltip: what it is and what a good value looks like). One
# format per kind everywhere: distances in cm, fractions in %.
METRIC_ROWS: tuple[tuple[str, str, str, str], ...] = (
    (
        "rmse_overlap_m",
        "NN distance RMS, overlap",
        "cm",
        "RMS distance from each source point in the overlap to its nearest target "
        "point. Good: about the scan noise, under 1-2 cm on bark. The figure to "
        "judge fit by; it barely moves once the pose is right.",
    ),
    (
        "overlap_fraction",
        "Overlap",
        "%",
        "Share of source points with a target point within metrics.overlap_dist_m. "
        "It says how much the scans share, not how right the pose is: two scans "
        "from opposite sides of a tree share 30-60%.",
    ),
    (
        "hausdorff_p95_m",
        "NN distance, 95th pct.",
        "cm",
        "95% of source points lie closer than this to the target (either way). "
        "Large when one scan sees branches the other does not; compare before and "
        "after, do not judge it alone.",
    ),
    (
        "rmse_m",
        "NN distance RMS, all points",
        "cm",
        "The same RMS over all source points, also those the target never saw: "
        "it can rise while the pose improves. Judge by the overlap RMS.",
    ),
    (
        "hausdorff_m",
        "Largest gap (Hausdorff)",
        "cm",
        "Largest nearest-neighbour distance either way: set by the one branch only "
        "one scan sees. Not an error measure; shown for completeness.",
    ),
    (
        "confidence",
        "Confidence",
        "%",
        "How clearly the chosen candidate beats the best different one. Good: 30% "
        "or more; below it the verdict asks for a review.",
    ),
    ("iterations", "ICP iterations", "count", "Fine registration: iterations run."),
    (
        "fitness",
        "ICP inlier share",
        "%",
        "Fine: share of the points ICP used (within its last correspondence "
        "distance). Good: 30% or more on two-sided scans.",
    ),
    (
        "inlier_rmse_m",
        "ICP inlier RMSE",
        "cm",
        "Fine: RMS distance of the ICP's own inlier pairs (only those within its "
        "correspondence distance), so smaller than the overlap RMS. Good: < 1 cm.",
    ),
    ("converged", "ICP converged", "bool", "Fine: did the ICP converge. Good: yes."),
    (
        "rotation_error_deg",
        "Truth: rotation error",
        "deg",
        "Needs a truth file (File > Load truth). Good: < 0.1°; registered < 1°.",
    ),
    (
        "translation_error_m",
        "Truth: translation error",
        "cm",
        "Error of the estimate at the source origin. Good: < 1 cm.",
    ),
    (
        "gt_rmse_m",
        "Truth: point error RMS",
        "cm",
        "RMS distance between source points moved by the estimate and by the truth. "
        "Good: < 1 cm; registered < 5 cm.",
    ),
    ("registered", "Truth: registered", "bool", "Rotation < 1° and point error < 5 cm"),
)
