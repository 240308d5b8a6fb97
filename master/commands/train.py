"""`rhi train --decoder {conv,vae} [--config FILE] [--preset paper] [--device D] --out CKPT`: a summary printed.

It reads the configuration like `rhi experiment`: ``[train]`` and the camera's ``[camera] blur``."""
from __future__ import annotations

from rhi.master import config as configuration
from rhi.master.commands.experiment import add_device, add_preset

HELP = "train a visual decoder"


def add_arguments(parser) -> None:
    """`rhi train`'s arguments."""
    parser.add_argument("--decoder", choices=("conv", "vae"), required=True)
    parser.add_argument("--config", metavar="FILE")
    add_preset(parser)
    add_device(parser)
    parser.add_argument("--out", metavar="CKPT", required=True)


def run(args) -> int:
    """The body of `rhi train`: args has .decoder, .config, .out, and optionally .preset and .device
    (default auto); everything checked before training."""
    from rhi.components.vision.component import resolve_device
    from rhi.master.decoders.training import check_target, train_decoder, train_settings
    from rhi.master.outputs.out_file import guard_out_file

    config = configuration.load(args.config, preset_name=getattr(args, "preset", None))
    settings = train_settings(config)
    check_target(args.out)
    guard_out_file(args.out)  # what is there now: the checkpoint is never put over a file that appeared since
    device = resolve_device(getattr(args, "device", "auto"))
    metadata, seconds = train_decoder(args.decoder, args.out, settings, blur=config["camera"]["blur"], device=device)
    errors = metadata.get("hand_error", {})
    print(f"{args.decoder} decoder ({settings.preset}, {settings.resolution} px) saved to {args.out}: "
          f"validation MSE {metadata['validation_mse']:.3g} after {metadata['epochs_run']} epochs "
          f"(best {metadata['best_epoch']}), {seconds['training']:.0f} s training + "
          f"{seconds['data']:.0f} s data")
    checks = metadata.get("hand_error_checks_cm")
    if checks:
        print(f"hand error read off the check's held-out poses after each epoch: "
              f"{', '.join(f'{value:.3f}' for value in checks)} cm"
              + (f" (stopped: at most {settings.stop_hand_error_cm} cm)" if checks[-1] <= settings.stop_hand_error_cm
                 else ""))
    if errors:
        print(f"hand error on {errors['poses']} held-out poses: read off the prediction "
              f"{errors['read_off']['mean_cm']:.2f} cm mean ({errors['read_off']['max_cm']:.2f} max), "
              f"visual-only inference {errors['inference']['mean_cm']:.2f} cm mean "
              f"({errors['inference']['max_cm']:.2f} max)")
    return 0
