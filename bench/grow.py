"""More Gaussians for a benchmark than a short run grows: copies as densification would make them."""


def grow(trainer, factor, seed=0):
    """Give every Gaussian ``factor - 1`` jittered copies (same triangle), as densification would."""
    import torch

    from mogaface.core.avatar.densify import edit_rows

    g = trainer.avatar.gaussians
    generator = torch.Generator().manual_seed(seed)
    copies = {name: t.detach().repeat(factor - 1, *[1] * (t.dim() - 1)) for name, t in g.tensors().items()}
    copies["local_position"] = copies["local_position"] + 0.3 * torch.randn(
        copies["local_position"].shape, generator=generator)
    edit_rows(g, trainer.optimizer, None, copies)
    trainer.strategy._reset_statistics(len(g))
