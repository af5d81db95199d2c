"""``evaluate``: compare a reconstruction with ground truth (Chamfer-L1 and F1, albedo RMSE,
PSNR/SSIM) and print the table; the metrics are :mod:`backend.metrics.evaluate`."""

from __future__ import annotations

from ..metrics.evaluate import RESULT, VIEW_SETS, evaluate, table, write_report
from ..metrics.geometry import DEFAULT_SAMPLES


def add_arguments(parser):
    parser.add_argument("prediction", metavar="RUN_OR_MESH",
                        help=f"reconstructed mesh, or a run folder containing {RESULT}")
    parser.add_argument("--truth", required=True, metavar="GT",
                        help="ground-truth mesh, or a synthetic capture folder with ground_truth.mesh")
    parser.add_argument("--out", metavar="JSON", help="write the metrics as JSON here")
    parser.add_argument("--samples", type=int, default=DEFAULT_SAMPLES,
                        help="surface samples per mesh (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="sampling seed (default: %(default)s)")
    parser.add_argument("--align", choices=("none", "icp"), default="none",
                        help="'icp': fit a similarity transform of the prediction onto the truth "
                             "first (for reconstructions in another frame); default: none")
    parser.add_argument("--renders", metavar="DIR",
                        help="predicted renders of the truth capture's held-out (or --views) views "
                             "(<frame name>.exr or .png) for PSNR/SSIM")
    parser.add_argument("--views", choices=VIEW_SETS, default="held_out",
                        help="which ground-truth views --renders shows (default: %(default)s)")


def run(args) -> int:
    report = evaluate(args.prediction, args.truth, args.samples, args.seed, args.align, args.renders,
                      args.views)
    print(table(report))
    if args.out:
        write_report(args.out, report)
    return 0
