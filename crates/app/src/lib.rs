//! kilotouch application library: the command-line interface and (later) the GUI.
