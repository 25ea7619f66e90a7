"""Loscos, Drettakis, Robert 2000, *Interactive Virtual Relighting of Real Scenes* (seeds/loscos2000_…)."""

NODES: dict[str, str] = {
    "LoadScene": "nodes.loscos.scene:LoadScene",
    "ProjectTextures": "nodes.loscos.textures:ProjectTextures",
    "RadiositySolve": "nodes.loscos.radiosity:RadiositySolve",
    "TextureRefine": "nodes.loscos.radiosity:TextureRefine",
    "Unocclude": "nodes.loscos.relight:Unocclude",
    "Relight": "nodes.loscos.relight:Relight",
}
