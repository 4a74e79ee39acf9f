# 2-core machine: the first task's start after the command's, before (012b32b: the fork server imports zarr) and after
# (the server leaves zarr out) (startup_2core-2026-11-28b.txt). The code before from a worktree put first on PYTHONPATH:
#   git worktree add /tmp/headwt2 012b32b; mkdir -p /tmp/oldpkg2/patchcloud; cp /tmp/headwt2/stream/patchcloud/* /tmp/oldpkg2/patchcloud/
#   ln -s /tmp/headwt2/core /tmp/oldpkg2/patchcloud/core; ln -s /tmp/headwt2/stream /tmp/oldpkg2/patchcloud/stream
# Input: python tools/city_las.py /tmp/bench_scale/city-10000000.laz --points 10000000
cd /tmp/bench_scale
for i in 1 2 3 4 5 6; do
 for v in old new; do
  if [ $v = old ]; then P=/tmp/oldpkg2; else P=; fi
  s=$(date +%s.%N)
  PYTHONPATH=$P /work/main/.venv/bin/python -m patchcloud.stream.console normals city-10000000.laz o2.laz -q --workers 2 --overwrite --profile /tmp/pab.json
  e=$(date +%s.%N)
  /work/main/.venv/bin/python -c "
import json; p=json.load(open('/tmp/pab.json')); s=$s; e=$e
print('$v', 'started %.2f ready %.2f first %.2f wall %.2f'%(p['started']-s, p['ready']-s, min(t[1] for t in p['tasks'])-s, e-s))"
 done
done
