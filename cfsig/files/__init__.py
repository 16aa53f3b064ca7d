"""Files: reading meshes, finding them under folders, class files, the demo collection."""
