"""Loading a trained model: the shipped ones by name, or a file (read as data, never
unpickled). torch and the model code are imported here, on the first load, not before.
"""

from __future__ import annotations

import os

from gripdem.api.model import Model


def load_model(source: str | os.PathLike, device: str = "cpu", precision: str = "auto") -> Model:
    """Load a trained model: ``"pretrained:pbc"``, ``"pretrained:lebc"``, a run's
    ``checkpoints/best.safetensors`` or a Lightning ``.ckpt``.

    Files are read as data (safetensors with a JSON card; nothing is unpickled). ``device``:
    a torch device (``"cpu"``, ``"cuda"``). ``precision``: of the encoder, ``"auto"`` (the
    default of ``gripdem.predict``: bf16 where the device computes it natively, CPU
    avx512_bf16/AMX or CUDA 8.0+, else fp32), ``"fp32"`` or ``"bf16"``.

    Args:
        source: ``"pretrained:NAME"`` (``pbc``, ``lebc``, ``pbc-ensemble``, ``lebc-ensemble``:
            the models shipped with gripdem) or the path of a model file.
        device: the torch device the model runs on.
        precision: the encoder's arithmetic: ``"auto"``, ``"fp32"`` or ``"bf16"``.

    Returns:
        a ``Model``: its ``scene`` is the training scene, its ``card`` the file's card.

    Raises:
        FileNotFoundError: no such file, or no shipped model of that ``pretrained:`` name.
        CheckpointError: the file is not a gripdem model, its tensors do not fit its
            hyperparameters, or it would run code when loaded (nothing in it is run).
        ValueError: a ``precision`` that is not one of the above (when it is first used).

    Examples:
        >>> import gripdem
        >>> model = gripdem.load_model("pretrained:lebc")
        >>> model
        Model('pretrained:lebc': unwrapped encoding, history 10, horizon 10, lees_edwards,
        deterministic)
        >>> model.scene.boundary, model.scene.shear_rate
        ('lees_edwards', 1000.0)
        >>> gripdem.load_model("pretrained:walls")
        Traceback (most recent call last):
            ...
        FileNotFoundError: pretrained:walls: no such shipped model; available: pretrained:lebc,
        pretrained:lebc-ensemble, pretrained:pbc, pretrained:pbc-ensemble
    """
    from gripdem.inference.checkpoint import read_checkpoint
    from gripdem.inference.pretrained import resolve

    path = resolve(source)
    hparams, state, card = read_checkpoint(path)
    return Model(str(source), path, hparams, state, dict(card), device, precision)
