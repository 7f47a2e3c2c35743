"""``tactile-jax simulate``: a scene from the space-domain simulator, written as a recording file."""

from __future__ import annotations

import dataclasses

import click

from ..errors import TactileInputError
from .common import parse_floats, user_errors


@click.command(short_help="Simulate a scene into a recording file.")
@click.option("--out", "out", required=True, type=click.Path(dir_okay=False), help="Recording file to write (.h5, .hdf5 or .npz).")
@click.option("--texture", type=click.Choice(["random", "grating", "net", "directional", "brushed", "modes"]),
              default="random", show_default=True,
              help="random (foamed polystyrene), grating (1-D, like the paper's pipes), net (wire net), directional"
              " (anisotropic random, 3:1 along x), brushed (random, correlation 2x longer along ridges across"
              " --angle) or modes (300 plane waves, seeded by --seed).")
@click.option("--pitch", type=float, default=None, help="Grating or net pitch, m (defaults 1.5e-3 and 0.5e-3).")
@click.option("--angle", type=float, default=0.0, show_default=True,
              help="Grating or net wavevector (brushed: ridge normal) angle from the x axis, degrees.")
@click.option("--shear", type=float, default=0.0, show_default=True,
              help="Net only: the second family's angle off perpendicular to the first, degrees.")
@click.option("--velocity", default="0.023,0.0", show_default=True, help="Slip vx,vy in m/s.")
@click.option("--contact-radius", type=float, default=None, help="Contact radius a, m (default 3e-3 unless --contact-depth).")
@click.option("--contact-depth", type=float, default=None, help="Contact depth, m; a = sqrt(R d) with R = 30 mm.")
@click.option("--window", type=click.Choice(["gaussian", "hertz"]), default="gaussian", show_default=True)
@click.option("--fs", type=float, default=1000.0, show_default=True, help="Sample rate, Hz.")
@click.option("--duration", type=float, default=16.0, show_default=True, help="Seconds.")
@click.option("--snr-db", type=float, default=50.0, show_default=True, help="Signal-to-noise ratio in dB (see Scene).")
@click.option("--noiseless", is_flag=True, help="No additive noise.")
@click.option("--gains", default="1,1,1,1", show_default=True, help="Per-probe gains x1,x2,y1,y2.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--records", type=int, default=1, show_default=True, help="Records to write (n, 4, N), seeds seed..seed+n-1.")
@user_errors
def simulate(out, texture, pitch, angle, shear, velocity, contact_radius, contact_depth, window, fs, duration,
             snr_db, noiseless, gains, seed, records):
    """Simulate a scene and write it as a recording file with its truth."""
    import math

    import numpy as np

    from ..io.files import write_recording
    from ..simulation.scene import Scene, simulate as run
    from ..simulation.texture import DirectionalTexture, Grating, ModeTexture, RandomTexture, StretchedTexture, WireNet

    if texture == "random":
        tex = RandomTexture()
    elif texture == "grating":
        tex = Grating(pitch=pitch or 1.5e-3, angle=math.radians(angle))
    elif texture == "directional":
        tex = DirectionalTexture()
    elif texture == "brushed":
        tex = StretchedTexture(angle=math.radians(angle))
    elif texture == "modes":
        tex = ModeTexture(seed=seed)
    else:
        tex = WireNet(pitch=pitch or 0.5e-3, angle=math.radians(angle), shear=math.radians(shear))
    if shear and texture != "net":
        raise TactileInputError(f"--shear applies to --texture net only, got --texture {texture}", code="bad_setting")
    if contact_radius is None and contact_depth is None:
        contact_radius = 3e-3
    if records < 1:
        raise TactileInputError(f"--records must be at least 1, got {records}", code="bad_setting")
    scene = Scene(texture=tex, velocity=parse_floats(velocity, 2, "velocity"), contact_radius=contact_radius,
                  contact_depth=contact_depth, window=window, fs=fs, duration=duration,
                  snr_db=None if noiseless else snr_db, gains=parse_floats(gains, 4, "gains"), seed=seed)
    recs = [run(dataclasses.replace(scene, seed=seed + i)) for i in range(records)]
    rec = recs[0]
    if records > 1:
        rec = dataclasses.replace(rec, signals=np.stack([r.signals for r in recs]),
                                  truth={**rec.truth, "seeds": [seed + i for i in range(records)]})
    path = write_recording(out, rec)
    t = rec.truth
    click.echo(f"wrote {path}: {records} x 4 x {rec.n_samples} samples at {rec.fs:g} Hz; "
               f"vx = {100 * t['vx']:.3f} cm/s, vy = {100 * t['vy']:.3f} cm/s, a = {1e3 * t['a']:.3f} mm ({t['window']})")
