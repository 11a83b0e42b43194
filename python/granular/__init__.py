"""hdGranular's usd-core front end: the granular schema, a USD stage reader that fills
core's SceneDesc, and the `granular` command (render, info, export-vdb).

Importing this package registers the codeless schema plugin in ../../schemas (or
$GRANULAR_SCHEMA_DIR) with USD, before or after `pxr` was first imported, as long as
USD's schema registry has not been built yet; `schema_registered()` says whether it
worked.
"""
import os
from pathlib import Path

__version__ = "0.1.0"

SCHEMA_DIR = Path(os.environ.get("GRANULAR_SCHEMA_DIR") or Path(__file__).resolve().parents[2] / "schemas")


def _register_schema_plugin():
    paths = [p for p in os.environ.get("PXR_PLUGINPATH_NAME", "").split(os.pathsep) if p]
    if str(SCHEMA_DIR) not in paths:
        os.environ["PXR_PLUGINPATH_NAME"] = os.pathsep.join(paths + [str(SCHEMA_DIR)])
    # In case pxr was imported first and its plugin registry has read the variable
    # already (registering the same folder twice is harmless).
    from pxr import Plug
    Plug.Registry().RegisterPlugins(str(SCHEMA_DIR))


_register_schema_plugin()


def schema_registered():
    """True when USD knows GranularAggregateAPI and GranularGrainAPI."""
    from pxr import Usd
    reg = Usd.SchemaRegistry()
    return all(reg.FindAppliedAPIPrimDefinition(n) is not None for n in ("GranularAggregateAPI", "GranularGrainAPI"))
