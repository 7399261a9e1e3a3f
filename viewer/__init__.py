"""gsz.viewer: the interactive viewer (gsz-view) lands here; see the viewer issue."""
