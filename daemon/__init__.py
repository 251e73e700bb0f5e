"""ahrsd.daemon"""
