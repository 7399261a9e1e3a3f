"""gsz.kernels"""
