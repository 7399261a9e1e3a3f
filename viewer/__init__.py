"""gsz.viewer"""
