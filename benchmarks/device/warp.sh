#!/usr/bin/env bash
# On the GPU machine: warp-lang's part N (1, 2, 3) kept outside the checkout; any call unpacks dm_control's
# suite where .whl-dmc came, and the rest of dm_control where .whl-dmc2 came (carry each beside a part whose
# sum stays under the 64 MiB limit: .whl-dmc with .wp3, .whl-dmc2 with .wp2); the third joins the parts and
# installs warp-lang.
set -euo pipefail
mkdir -p /root/wparts && cp .wp"$1"/* /root/wparts/
site=$(python -c 'import site; print(site.getsitepackages()[0])')
if [ -d .whl-dmc ]; then
  tar xzf .whl-dmc/dm_control_suite.tgz -C "$site"
fi
if [ -d .whl-dmc2 ]; then
  tar xzf .whl-dmc2/dm_control_rest.tgz -C "$site"
  python -m pip install -q --no-deps .whl-dmc2/*.whl
fi
if [ "$1" = 3 ]; then
  wheel=/root/warp_lang-1.19.0-py3-none-manylinux_2_28_x86_64.whl
  cat /root/wparts/part.* > "$wheel" && python -m pip install -q --no-deps "$wheel"
  python -c "import warp; print('warp', warp.__version__)"
fi
