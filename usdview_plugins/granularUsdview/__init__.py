"""usdview menu commands for granular aggregates (menu "Granular"):

- Statistics of Selected Prim: grains, tiles, TT and RTE parameters;
- Export Coarse Density to VDB...: the selected aggregate's σ_t as an OpenVDB grid;
- Toggle EPT-only Reference: the Granular delegate's technique between ept and hybrid.

The logic is in commands.py (no GUI). Load with
  PXR_PLUGINPATH_NAME=<repo>/usdview_plugins:<repo>/schemas:<build>/hdGranular/plugin
  PYTHONPATH=<repo>/usdview_plugins:<repo>/python:<build>/python
"""
try:  # usdview's Python; usd-core has no Usdviewq, and commands.py works without it
    from pxr.Usdviewq.plugin import PluginContainer as _PluginContainer
except ImportError:
    _PluginContainer = None

if _PluginContainer is not None:
    from .container import GranularPluginContainer  # noqa: F401
