"""gsz.encoder"""
