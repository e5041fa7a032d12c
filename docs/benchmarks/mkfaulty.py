"""Copy a simulated dataset with issue #26's input faults: 3 s of frames cut from images.txt at
60 s, 5 % of the listed frames truncated to half their bytes, 2 % of the altimeter readings
set to nan. Usage: python3 mkfaulty.py SRC DST SEED (the source is not modified)."""
import sys, shutil, random, os
src, dst, seed = sys.argv[1], sys.argv[2], int(sys.argv[3])
rng = random.Random(seed)
shutil.rmtree(dst, ignore_errors=True); shutil.copytree(src, dst)
uav = os.path.join(dst, 'uav')
lines = open(os.path.join(uav, 'images.txt')).read().splitlines()
t0 = None
def t(l): return float(l.split()[0])
data = [l for l in lines if not l.startswith('#') and l.strip()]
g0 = t(data[0]) + 60.0
kept = [l for l in lines if l.startswith('#') or not l.strip() or not (g0 <= t(l) < g0 + 3.0)]
open(os.path.join(uav, 'images.txt'), 'w').write('\n'.join(kept) + '\n')
listed = [l for l in kept if not l.startswith('#') and l.strip()]
for l in rng.sample(listed, round(len(listed) * 0.05)):
    p = os.path.join(uav, l.split()[1]); b = open(p, 'rb').read(); open(p, 'wb').write(b[:len(b)//2])
alt = open(os.path.join(uav, 'altimeter.txt')).read().splitlines()
idx = [i for i, l in enumerate(alt) if not l.startswith('#') and l.strip()]
for i in rng.sample(idx, round(len(idx) * 0.02)):
    alt[i] = alt[i].split()[0] + ' nan'
open(os.path.join(uav, 'altimeter.txt'), 'w').write('\n'.join(alt) + '\n')
print(dst, len(lines) - len(kept), 'cut', round(len(listed) * 0.05), 'truncated', round(len(idx) * 0.02), 'nan')
