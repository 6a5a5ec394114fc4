"""napari dock widgets (Qt). Thin: collect parameters, run the core in a
worker thread, put results into layers. The core never imports this."""
