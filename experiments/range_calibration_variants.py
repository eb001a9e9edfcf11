"""Range-calibration variants on stored per-frame IR estimates (evaluate --json with ir_est):
the pipeline's fuse -> range_model -> rescale -> fuse, with the range model's weights varied."""
import json, sys
import numpy as np, jax, jax.numpy as jnp
from pathlib import Path
from rhaml_jax import pgo, pipeline, metrics
from rhaml_jax.data import read_bop
from rhaml_jax.sequence import group_scenes, load_scene
from rhaml_jax.pgo import _scale

def run(js, data, variant, key):
    rows = json.load(open(js))['frames']
    frames = read_bop(Path(data))
    sc = load_scene(list(group_scenes(frames).values())[0])
    seq = sc.seq
    xypsi = jnp.asarray([r[key] for r in rows], jnp.float32)
    fp = jnp.asarray([r['ir_flip_prob' if key == 'ir_est' else 'iml_flip_prob'] for r in rows], jnp.float32)
    det = jnp.asarray([r['detected'] for r in rows])
    cfg = pgo.FusionConfig()
    obs = pgo.observation_from_xy_yaw_rp(xypsi, None)
    rv = pgo.rendezvous_from_frames(seq.odom_a, seq.odom_b, obs, seq.a_observes)
    f1 = pgo.fuse_jit(rv, cfg, valid=det, flip_prob=fp)
    used = (f1.inlier & det).astype(jnp.float32)
    if variant == 'off':
        c = jnp.zeros(2)
    elif variant == 'on':
        c = pgo.range_model(rv, f1.odom_a_T_odom_b, used, cfg.obs_sigma_xy_m)
    elif variant == 'relw':  # sigma proportional to the range (a percent error): weights 1/r^2
        r = jnp.hypot(xypsi[:, 0], xypsi[:, 1])
        c = pgo.range_model(rv, f1.odom_a_T_odom_b, used * (4.5 / r) ** 2, cfg.obs_sigma_xy_m)
    elif variant == 'slope':
        c = pgo.range_model(rv, f1.odom_a_T_odom_b, used, cfg.obs_sigma_xy_m, slope=True)
    f2 = pgo.fuse_jit(pgo.rescale_observations(rv, c), cfg, valid=det, flip_prob=fp)
    est = np.asarray(f2.relative)
    m = metrics.summarize(est[sc.observed], sc.gt[sc.observed])
    return m['dx_cm'][0], m['dy_cm'][0], m['ate'], [round(float(v), 4) for v in c]

out = []
for js, data in zip(sys.argv[1::2], sys.argv[2::2]):
    for key in ['ir_est', 'iml_est']:
        for v in ['off', 'on', 'relw', 'slope']:
            dx, dy, ate, c = run(js, data, v, key)
            out.append(dict(js=js, key=key, variant=v, dx=dx, dy=dy, ate=ate, c=c))
            print(f'{Path(js).name:45s} {key:7s} {v:6s} dx {dx:5.2f} dy {dy:5.2f} ate {ate:.4f} c {c}', flush=True)
json.dump(out, open('calvar_out.json', 'w'))
