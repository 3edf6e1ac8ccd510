"""The contact-correction and ensemble options of the surrogate benchmarks, and the stepper
settings and model overrides they ask for (one place for ``surrogate_rollout.py`` and its
member-cost timing)."""

from __future__ import annotations

import argparse

from gripdem.inference.contacts import CORRECTION_TOLERANCE
from gripdem.inference.stepper import StepperSettings


def add_correction_options(parser: argparse.ArgumentParser) -> None:
    """--correction-tolerance, --contact-capture, --contact-overlap, --noise-scale."""
    parser.add_argument(
        "--correction-tolerance",
        type=float,
        default=CORRECTION_TOLERANCE,
        help="overlaps the contact correction leaves, in contact distances",
    )
    parser.add_argument(
        "--contact-capture",
        type=float,
        metavar="GAP",
        help="pairs closer than GAP contact distances are pulled into contact (default: the "
        "model's own contact_capture)",
    )
    parser.add_argument(
        "--contact-overlap",
        default="observed",
        metavar="F",
        help="where corrected pairs end, a fraction of the contact distance inside it "
        "(default observed: the observed frame's resting contacts; 0: exactly touching)",
    )
    parser.add_argument(
        "--noise-scale",
        type=float,
        metavar="F",
        help="an ensemble's latent noise times F (default: the model's own noise_scale)",
    )


def stepper_settings(args, relaxation=None) -> StepperSettings:
    """The stepper settings the options ask for (None: the stepper's and the model's own)."""
    overlap = args.contact_overlap
    return StepperSettings(
        link=args.link,
        contact_correction=not args.no_correction and relaxation is None,
        correction_tolerance=args.correction_tolerance,
        relaxation=relaxation,
        contact_capture=args.contact_capture,
        contact_overlap=None if overlap == "observed" else float(overlap),
    )


def rollout_options(model, args) -> None:
    """``--noise-scale`` in place of the model's own inflation (an ensemble's ablation)."""
    if args.noise_scale is not None:
        model.hparams.noise_scale = float(args.noise_scale)
