"""forestslam: LiDAR SLAM and tree mapping for forest machines."""

import pkgutil

__version__ = "0.1.0"

# Lets a development build of `_core` (build/dev-*/python/forestslam) sit beside the sources.
__path__ = pkgutil.extend_path(__path__, __name__)
