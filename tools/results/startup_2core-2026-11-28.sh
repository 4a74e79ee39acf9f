# 2-core machine: the first task's start after the command's, old and new console entry (startup_2core-2026-11-28.txt).
# Input: python tools/city_las.py /tmp/bench_scale/city-10000000.laz --points 10000000
cd /tmp/bench_scale
for i in 1 2 3 4 5 6; do
 for v in old new; do
  if [ $v = old ]; then CMD="/work/main/.venv/bin/python -c 'from patchcloud.stream.cli import run; run()'"; else CMD="/work/main/.venv/bin/python -c 'from patchcloud.stream.console import run; run()'"; fi
  s=$(date +%s.%N)
  eval "$CMD normals city-10000000.laz o2.laz -q --workers 2 --overwrite --profile /tmp/pab.json"
  e=$(date +%s.%N)
  /work/main/.venv/bin/python -c "
import json; p=json.load(open('/tmp/pab.json')); s=$s; e=$e
print('$v', 'started %.2f ready %.2f first %.2f wall %.2f'%(p['started']-s, p['ready']-s, min(t[1] for t in p['tasks'])-s, e-s))"
 done
done
